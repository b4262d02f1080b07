//! DBC files: tolerant loading (via `can-dbc`) and decoding of signals from frame payloads with
//! our own bit extraction. No vehicle policy: which signal means what lives in [`crate::signals`].
