//! The alert rules' settings (`[alerts]`): the thresholds, windows and hysteresis of the two
//! maintenance alerts ([`super::Kind`]), with the defaults of the source study.
//!
//! What it is: a name for the `[alerts]` table of the monitor's settings file
//! ([`crate::observer::alerts::AlertConfig`]), so that `shimmy estimate` and shimmyd read one
//! schema and apply it with the same rules ([`super::AlertBook`]). What it is not: the loading or validation of a configuration file; shimmyd checks the
//! values when it loads its configuration (`daemon::config`).

/// `[alerts]`: the two maintenance alerts and their hysteresis.
pub type AlertsSection = crate::observer::alerts::AlertConfig;
