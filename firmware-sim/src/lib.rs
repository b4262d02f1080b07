//! firmware-sim: simulated vehicle ECUs that drive the shimmy model with a known clearance and
//! put the frames of the reference bus (`dbc/`) on a CAN interface or into a candump log.
//!
//! Not yet implemented: see issue 4. This crate currently only exists so the workspace layout is fixed.
