//! shimmyd's configuration: one TOML file (config/shimmyd.toml is the documented default;
//! docs/CONFIG.md documents every key).
//!
//! What it is: the serde types (every table `deny_unknown_fields`, so a typo is an error, not a
//! silently ignored key) and [`Config::load`], which parses, resolves relative paths against the
//! file's directory and checks what serde cannot express. Every error names the key and the
//! problem, e.g. `alerts.shimmy_deg: must be > 0 (got -0.2)`.
//!
//! The daemon's file holds what is the daemon's (inputs, vehicle, outputs, log, MQTT) and names
//! the monitor's settings file with the top-level key `monitor` ([`ObserverConfig`], the file
//! `shimmy estimate --config` reads), which it loads here. The earlier layout, with `[events]`,
//! `[alerts]` and `[observer.*]` written into the daemon's file, is still read, with deprecation
//! warnings ([`Config::warnings`]); giving both is an error.
//!
//! What it is not: the loading of the files the daemon uses later (DBC, mapping, vehicle): the
//! daemon does that at start-up and reports their errors with their own file names.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use crate::alerts::config::AlertsSection;
use crate::journal::{FsyncPolicy, JournalConfig};
use crate::observer::estimator::EstimatorConfig;
use crate::observer::{FeatureConfig, ObserverConfig};

/// The whole file.
///
/// `events`, `alerts` and `observer` hold the settings in effect whichever way they were given
/// (from the `monitor` file, or from the deprecated tables of the daemon's own file);
/// `settings` holds all of them as the observer takes them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The monitor's settings file (config/observer.toml's schema: `[events]`, `[features]`,
    /// `[estimator]`, `[alerts]`), relative to this file. Without it, and without the deprecated
    /// tables below, the built-in defaults apply.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub monitor: Option<PathBuf>,
    pub input: Input,
    #[serde(default)]
    pub vehicle: VehicleSection,
    /// Deprecated in the daemon's file: `[events]` of the `monitor` file.
    #[serde(default)]
    pub events: EventsSection,
    /// Deprecated in the daemon's file: `[alerts]` of the `monitor` file.
    #[serde(default)]
    pub alerts: AlertsSection,
    pub outputs: Outputs,
    #[serde(default)]
    pub log: LogSection,
    /// Deprecated in the daemon's file: `[features]` and `[estimator]` of the `monitor` file.
    #[serde(default)]
    pub observer: ObserverSection,
    #[serde(default)]
    pub mqtt: MqttSection,
    /// The profile `input.profile` names, loaded (not part of the file).
    #[serde(skip)]
    pub profile: Option<crate::profile::Profile>,
    /// The monitor's settings in effect, complete (not part of the file).
    #[serde(skip)]
    pub settings: ObserverConfig,
    /// Deprecation warnings for what the file (or the `monitor` file) uses, each naming what
    /// replaces it (not part of the file). shimmyd prints them at start.
    #[serde(skip)]
    pub warnings: Vec<String>,
}

/// Tables of the daemon's file that moved to the monitor's settings file: (table in the daemon's
/// file, the table of the monitor file that replaces it). Read for one more release.
pub const DEPRECATED_TABLES: &[(&str, &str)] = &[
    ("events", "events"),
    ("alerts", "alerts"),
    ("observer.features", "features"),
    ("observer.features.sensor", "features.sensor"),
    ("observer.estimator", "estimator"),
];

/// The deprecated tables `raw` (a daemon file as written) contains, as (old, new) pairs (an
/// empty `[observer]` holds no setting and is not one of them).
fn deprecated_tables(raw: &toml::Table) -> Vec<(&'static str, &'static str)> {
    let mut found = Vec::new();
    for &(old, new) in DEPRECATED_TABLES {
        let mut t = Some(raw);
        for part in old.split('.') {
            t = t.and_then(|t| t.get(part)).and_then(|v| v.as_table());
        }
        if t.is_some() {
            found.push((old, new));
        }
    }
    found
}

/// `[input]`: where frames come from and how to read them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Input {
    /// SocketCAN interfaces read live (read-only). Ignored when `--replay` is given.
    #[serde(default)]
    pub interfaces: Vec<String>,
    /// Logs replayed when no interface is configured and `--replay` is not given.
    #[serde(default)]
    pub replay: Vec<PathBuf>,
    /// Replay as fast as possible instead of at recorded timing.
    #[serde(default)]
    pub fast: bool,
    /// The vehicle profile (config/vehicles/<name>, or a path to one): the car's DBC, mapping,
    /// chassis and response table. Looked up beside this file (`vehicles/<name>`) and on the
    /// profile search path ([`crate::profile`]). `dbc`, `mapping` and `vehicle.table` override
    /// the profile's.
    #[serde(default)]
    pub profile: Option<String>,
    /// The DBC describing the bus (required without a profile).
    #[serde(default)]
    pub dbc: Option<PathBuf>,
    /// The signal mapping (required without a profile; a profile's mapping.toml, e.g.
    /// config/vehicles/*/mapping.toml).
    #[serde(default)]
    pub mapping: Option<PathBuf>,
}

/// `[vehicle]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleSection {
    /// Vehicle parameters of the shimmy model (config/vehicle/*.toml); MODEL.md §9 defaults when
    /// absent.
    #[serde(default)]
    pub params: Option<PathBuf>,
    /// The observer's response table (`shimmy calibrate`); without it no clearance estimate is
    /// made (the shimmy-amplitude alert still works).
    #[serde(default)]
    pub table: Option<PathBuf>,
    /// The response table of the EPS torsion-bar torque (`shimmy calibrate --signal torque`);
    /// default: the profile's `torque_table` when its mapping maps the torque. Where the bus
    /// carries a live torque the estimate comes from it, else from the angle table.
    #[serde(default)]
    pub torque_table: Option<PathBuf>,
    /// Logs of this vehicle driven when its joints' clearance was known (its first drives
    /// after a joint replacement): their braking events become the vehicle's baseline, which
    /// conditions every estimate (`shimmy estimate --baseline`; docs/ACCURACY.md). Read at
    /// start; while set it takes the place of a baseline the saved state holds, except one
    /// collected after a joint replacement marked later (`<state_dir>/joints_replaced`,
    /// [`super::joints`]), which is newer.
    #[serde(default)]
    pub baseline_logs: Vec<PathBuf>,
    /// The joints' clearance during the `baseline_logs` (mm); also the new joints' clearance
    /// of a joint replacement whose marker gives none.
    #[serde(default = "default_baseline_clearance_mm")]
    pub baseline_clearance_mm: f64,
    /// After a joint replacement (the marker `<state_dir>/joints_replaced`): how many used
    /// braking events become the new baseline (1..=1000).
    #[serde(default = "default_baseline_events")]
    pub baseline_events: u32,
    /// Odometer at first start when no state exists yet (km).
    #[serde(default)]
    pub initial_odometer_km: f64,
}

fn default_baseline_clearance_mm() -> f64 {
    0.03
}

fn default_baseline_events() -> u32 {
    10
}

/// Most events `vehicle.baseline_events` may ask for.
pub const MAX_BASELINE_EVENTS: u32 = 1000;

/// A configuration without `[vehicle]` (or with an empty one) has what each key defaults to.
impl Default for VehicleSection {
    fn default() -> Self {
        VehicleSection {
            params: None,
            table: None,
            torque_table: None,
            baseline_logs: Vec::new(),
            baseline_clearance_mm: default_baseline_clearance_mm(),
            baseline_events: default_baseline_events(),
            initial_odometer_km: 0.0,
        }
    }
}

/// `[events]`: which brake applications count (article §2.1.2 validity range).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EventsSection {
    pub min_speed_kmh: f64,
    pub max_speed_kmh: f64,
    pub min_decel_g: f64,
    pub max_decel_g: f64,
    /// Largest |steering-wheel angle| of a "straight" event (deg).
    pub max_steer_deg: f64,
}

impl Default for EventsSection {
    fn default() -> Self {
        EventsSection {
            min_speed_kmh: 20.0,
            max_speed_kmh: 120.0,
            min_decel_g: 0.3,
            max_decel_g: 0.8,
            max_steer_deg: 15.0,
        }
    }
}

/// `[outputs]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Outputs {
    /// Directory of the event/alert journal.
    pub journal_dir: PathBuf,
    /// `"always"` (fsync every record) or `"interval"` (every `fsync_interval_ms`).
    #[serde(default = "default_fsync")]
    pub fsync: String,
    #[serde(default = "default_fsync_ms")]
    pub fsync_interval_ms: u64,
    /// Rotate the journal's current file at this size (MiB).
    #[serde(default = "default_rotate_mib")]
    pub rotate_mib: f64,
    /// Directory of the persisted state (estimate, events, odometer); `--state-dir` overrides.
    pub state_dir: PathBuf,
    /// Send SHIMMY_01 of dbc/shimmy_reference.dbc on the bus. Off by default: the daemon is
    /// read-only unless this is explicitly true.
    #[serde(default)]
    pub transmit: bool,
    /// Interface to transmit on (required when `transmit = true`).
    #[serde(default)]
    pub transmit_interface: Option<String>,
}

fn default_fsync() -> String {
    "always".into()
}
fn default_fsync_ms() -> u64 {
    200
}
fn default_rotate_mib() -> f64 {
    16.0
}

/// `[log]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LogSection {
    /// Period of the counters line on stderr (s); 60 = per minute.
    pub counters_interval_s: u64,
}

impl Default for LogSection {
    fn default() -> Self {
        LogSection {
            counters_interval_s: 60,
        }
    }
}

/// `[observer]`: the clearance observer's feature and estimator settings (the same keys as
/// `[features]` and `[estimator]` of config/observer.toml, see [`crate::observer`]); every key
/// optional, defaults as there. Detection thresholds are `[events]` above.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserverSection {
    pub features: FeatureConfig,
    pub estimator: EstimatorConfig,
}

/// `[mqtt]`: the optional outgoing MQTT client to a fleet backend ([`super::mqtt`]). Off unless
/// `enabled = true`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MqttSection {
    pub enabled: bool,
    /// Broker host name or address (required when enabled). With TLS, the name (or IP address)
    /// the broker's certificate must carry.
    pub host: String,
    /// Broker port; default 8883 with TLS, 1883 with `transport = "tcp"` ([`Self::port`]).
    pub port: Option<u16>,
    /// `"tls"` or `"tcp"`. Unset means TLS when `ca_file` is given; an enabled client with
    /// neither is refused: plain text is sent only when the file says `transport = "tcp"`.
    pub transport: Option<Transport>,
    /// PEM file of the CA(s) the broker's certificate must chain to (required with TLS).
    pub ca_file: Option<PathBuf>,
    /// PEM file of this vehicle's client certificate (chain), for mutual TLS; with `key_file`.
    pub cert_file: Option<PathBuf>,
    /// PEM file of the client certificate's private key (PKCS#8, PKCS#1 or SEC1).
    pub key_file: Option<PathBuf>,
    /// MQTT client id (required when enabled); also the vehicle's name in topics and ids.
    pub client_id: String,
    /// The fleet the vehicle belongs to (required when enabled): a topic level.
    pub fleet: String,
    /// Topics are `<topic_prefix>/v1/<fleet>/<client_id>/{event,estimate,alert,status}`.
    pub topic_prefix: String,
    /// MQTT 5 message expiry interval of estimates (s): a broker drops an estimate not
    /// delivered to a subscriber within this time (a newer one supersedes it).
    pub estimate_expiry_s: u32,
    /// 0, 1 or 2. 1 (at least once) or 2 are needed for the no-loss guarantee.
    pub qos: u8,
    pub keep_alive_s: u64,
    /// Pause between connection attempts while the broker is unreachable (s).
    pub reconnect_s: f64,
    /// The cursor into the journal (first record not yet delivered); default
    /// `<state_dir>/mqtt-cursor.json`. The journal itself is the queue.
    pub cursor_file: Option<PathBuf>,
    /// Queue bound: beyond either limit the oldest queued messages are dropped (counted,
    /// logged, and reported to the backend in every message's `queue_dropped`; they stay in
    /// the journal).
    pub queue_max_messages: usize,
    pub queue_max_mib: f64,
    /// On stop, wait up to this long for the queue to drain (s); the rest is sent after the
    /// next start.
    pub drain_timeout_s: f64,
}

/// `mqtt.transport`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    /// TLS 1.2/1.3 (rustls), the broker verified against `ca_file`.
    Tls,
    /// Plain TCP: unencrypted and the broker unauthenticated.
    Tcp,
}

impl MqttSection {
    /// The transport in effect: the one written, else TLS when `ca_file` is given. `None`
    /// (neither) is refused by the configuration check when MQTT is enabled.
    pub fn transport(&self) -> Option<Transport> {
        self.transport
            .or(self.ca_file.as_ref().map(|_| Transport::Tls))
    }

    /// The port in effect: `port`, else 8883 (MQTT over TLS) or 1883 (plain).
    pub fn port(&self) -> u16 {
        self.port.unwrap_or(match self.transport() {
            Some(Transport::Tcp) => 1883,
            _ => 8883,
        })
    }
}

impl Default for MqttSection {
    fn default() -> Self {
        MqttSection {
            enabled: false,
            host: String::new(),
            port: None,
            transport: None,
            ca_file: None,
            cert_file: None,
            key_file: None,
            client_id: String::new(),
            fleet: String::new(),
            topic_prefix: "shimmy".into(),
            estimate_expiry_s: 86_400,
            qos: 1,
            keep_alive_s: 30,
            reconnect_s: 2.0,
            cursor_file: None,
            queue_max_messages: 10_000,
            queue_max_mib: 8.0,
            drain_timeout_s: 2.0,
        }
    }
}

impl Config {
    /// Parses `text`; relative paths are resolved against `base` (the file's directory).
    pub fn from_toml_str(text: &str, base: &Path) -> anyhow::Result<Config> {
        Config::from_toml_str_with(text, base, None)
    }

    /// [`Self::from_toml_str`] with the car replaced by `profile` (the command line's
    /// `--profile`): the file's `input.profile`, `input.dbc`, `input.mapping` and
    /// `vehicle.table` give way to the profile's.
    pub fn from_toml_str_with(
        text: &str,
        base: &Path,
        profile: Option<&str>,
    ) -> anyhow::Result<Config> {
        Config::parse(text, base, profile, "")
    }

    /// [`Self::from_toml_str_with`]; `origin` starts each warning about the text itself (the
    /// file's name, when there is one).
    fn parse(
        text: &str,
        base: &Path,
        profile: Option<&str>,
        origin: &str,
    ) -> anyhow::Result<Config> {
        let mut cfg: Config = toml::from_str(text).map_err(|e| anyhow::anyhow!("{e}"))?;
        // It parsed, so it is a table.
        let raw: toml::Table = toml::from_str(text).map_err(|e| anyhow::anyhow!("{e}"))?;
        cfg.resolve(base);
        cfg.apply_monitor(&raw, origin)?;
        if let Some(name) = profile {
            cfg.input.profile = Some(name.to_string());
            cfg.input.dbc = None;
            cfg.input.mapping = None;
            cfg.vehicle.table = None;
            cfg.vehicle.torque_table = None;
        }
        cfg.apply_profile(base)?;
        cfg.validate_daemon()?;
        match &cfg.monitor {
            Some(m) => cfg
                .validate_settings()
                .with_context(|| format!("monitor: in {}", m.display()))?,
            None => cfg.validate_settings()?,
        }
        Ok(cfg)
    }

    /// Fills in the monitor's settings: from the `monitor` file when given (an error if the
    /// daemon's file also has any of [`DEPRECATED_TABLES`]), otherwise from those tables of the
    /// daemon's file, with a deprecation warning for each.
    fn apply_monitor(&mut self, raw: &toml::Table, origin: &str) -> anyhow::Result<()> {
        let old = deprecated_tables(raw);
        if let Some(path) = &self.monitor {
            if let Some((t, new)) = old.first() {
                bail!(
                    "monitor = {:?} and [{t}] both given: the monitor's settings are read from one \
                     place; move the keys of [{t}] into [{new}] of {}",
                    path.display().to_string(),
                    path.display()
                );
            }
            let (settings, warnings) = ObserverConfig::load_with_warnings(path)
                .with_context(|| format!("monitor: {}", path.display()))?;
            self.events = EventsSection {
                min_speed_kmh: settings.events.min_speed_kmh,
                max_speed_kmh: settings.events.max_speed_kmh,
                min_decel_g: settings.events.min_decel_g,
                max_decel_g: settings.events.max_decel_g,
                max_steer_deg: settings.events.max_steer_deg,
            };
            self.alerts = settings.alerts.clone();
            self.observer = ObserverSection {
                features: settings.features.clone(),
                estimator: settings.estimator.clone(),
            };
            self.settings = settings;
            self.warnings.extend(warnings);
            return Ok(());
        }
        for (t, new) in old {
            self.warnings.push(format!(
                "{origin}[{t}] in the daemon's configuration is deprecated and will be removed in the \
                 next release; put its keys in [{new}] of the monitor's settings file \
                 (config/observer.toml) and name that file with the top-level key \
                 `monitor = \"observer.toml\"` (docs/CONFIG.md)"
            ));
        }
        if let Some(toml::Value::Table(a)) = raw.get("alerts") {
            self.warnings.extend(
                crate::observer::alerts::deprecations(a)
                    .into_iter()
                    .map(|w| format!("{origin}{w} (daemon configuration)")),
            );
        }
        let mut s = ObserverConfig::default();
        s.events.min_speed_kmh = self.events.min_speed_kmh;
        s.events.max_speed_kmh = self.events.max_speed_kmh;
        s.events.min_decel_g = self.events.min_decel_g;
        s.events.max_decel_g = self.events.max_decel_g;
        s.events.max_steer_deg = self.events.max_steer_deg;
        s.features = self.observer.features.clone();
        s.estimator = self.observer.estimator.clone();
        s.alerts = self.alerts.clone();
        self.settings = s;
        Ok(())
    }

    /// Loads `input.profile` and fills in what the file leaves to it: the DBC, the mapping and
    /// the response table.
    fn apply_profile(&mut self, base: &Path) -> anyhow::Result<()> {
        let Some(name) = &self.input.profile else {
            return Ok(());
        };
        let dir =
            crate::profile::find_in(name, &[base.join("vehicles")]).context("input.profile")?;
        let p = crate::profile::Profile::load_dir(&dir).context("input.profile")?;
        self.input.dbc.get_or_insert_with(|| p.dbc_path.clone());
        self.input
            .mapping
            .get_or_insert_with(|| p.mapping_path.clone());
        if self.vehicle.table.is_none() {
            // A profile whose table is not built yet still finds events; the daemon says so.
            self.vehicle.table = p.table_path.clone().filter(|t| t.is_file());
        }
        if self.vehicle.torque_table.is_none() && p.mapping.steer_torque.is_some() {
            self.vehicle.torque_table = p.torque_table_path.clone().filter(|t| t.is_file());
        }
        self.profile = Some(p);
        Ok(())
    }

    /// The DBC and mapping in use (the profile's unless overridden); `None` when neither a
    /// profile nor both files are configured (the daemon then identifies the car from its bus).
    pub fn bus_files(&self) -> Option<(&Path, &Path)> {
        Some((self.input.dbc.as_deref()?, self.input.mapping.as_deref()?))
    }

    /// Reads, parses and checks a config file; errors name the file, the key and the problem.
    pub fn load(path: &Path) -> anyhow::Result<Config> {
        Config::load_with_profile(path, None)
    }

    /// [`Self::load`] with the car replaced by `profile` ([`Self::from_toml_str_with`]).
    pub fn load_with_profile(path: &Path, profile: Option<&str>) -> anyhow::Result<Config> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        Config::parse(&text, base, profile, &format!("{}: ", path.display()))
            .with_context(|| format!("invalid config {}", path.display()))
    }

    /// Prints [`Self::warnings`] on stderr, one `warning:` line each.
    pub fn print_warnings(&self) {
        for w in &self.warnings {
            eprintln!("warning: {w}");
        }
    }

    fn resolve(&mut self, base: &Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        if let Some(p) = self.input.dbc.as_mut() {
            fix(p);
        }
        if let Some(p) = self.input.mapping.as_mut() {
            fix(p);
        }
        self.input.replay.iter_mut().for_each(fix);
        if let Some(p) = self.vehicle.params.as_mut() {
            fix(p);
        }
        if let Some(p) = self.vehicle.table.as_mut() {
            fix(p);
        }
        if let Some(p) = self.vehicle.torque_table.as_mut() {
            fix(p);
        }
        self.vehicle.baseline_logs.iter_mut().for_each(fix);
        if let Some(p) = self.monitor.as_mut() {
            fix(p);
        }
        fix(&mut self.outputs.journal_dir);
        fix(&mut self.outputs.state_dir);
        for p in [
            &mut self.mqtt.cursor_file,
            &mut self.mqtt.ca_file,
            &mut self.mqtt.cert_file,
            &mut self.mqtt.key_file,
        ]
        .into_iter()
        .flatten()
        {
            fix(p);
        }
    }

    /// The checks serde cannot express.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.validate_daemon()?;
        self.validate_settings()
    }

    /// The checks of the daemon's own settings.
    fn validate_daemon(&self) -> anyhow::Result<()> {
        if self.input.dbc.is_some() != self.input.mapping.is_some() {
            bail!(
                "input.dbc and input.mapping: give both (or input.profile, whose files fill in \
                 what is not given)"
            );
        }
        for (key, p) in [
            ("input.dbc", &self.input.dbc),
            ("input.mapping", &self.input.mapping),
            ("vehicle.params", &self.vehicle.params),
            ("vehicle.table", &self.vehicle.table),
            ("vehicle.torque_table", &self.vehicle.torque_table),
        ] {
            if let Some(p) = p {
                if !p.is_file() {
                    bail!("{key}: file {} does not exist", p.display());
                }
            }
        }
        for (i, p) in self.vehicle.baseline_logs.iter().enumerate() {
            if !p.is_file() {
                bail!(
                    "vehicle.baseline_logs[{i}]: file {} does not exist",
                    p.display()
                );
            }
        }
        let c = self.vehicle.baseline_clearance_mm;
        if !(c > 0.0 && c.is_finite()) {
            bail!("vehicle.baseline_clearance_mm: {c} is not a clearance above 0 mm");
        }
        let n = self.vehicle.baseline_events;
        if !(1..=MAX_BASELINE_EVENTS).contains(&n) {
            bail!("vehicle.baseline_events: must be 1..={MAX_BASELINE_EVENTS} (got {n})");
        }
        for (i, name) in self.input.interfaces.iter().enumerate() {
            if name.is_empty() || name.len() > 15 || name.contains('/') {
                bail!(
                    "input.interfaces[{i}]: `{name}` is not a network interface name (1-15 characters, no '/')"
                );
            }
        }
        if !self.vehicle.initial_odometer_km.is_finite() || self.vehicle.initial_odometer_km < 0.0 {
            bail!(
                "vehicle.initial_odometer_km: must be >= 0 (got {})",
                self.vehicle.initial_odometer_km
            );
        }
        let o = &self.outputs;
        match o.fsync.as_str() {
            "always" => {}
            "interval" => {
                if o.fsync_interval_ms == 0 || o.fsync_interval_ms > 60_000 {
                    bail!(
                        "outputs.fsync_interval_ms: must be 1..=60000 (got {})",
                        o.fsync_interval_ms
                    );
                }
            }
            other => bail!("outputs.fsync: must be \"always\" or \"interval\" (got \"{other}\")"),
        }
        if !(o.rotate_mib.is_finite() && o.rotate_mib >= 0.001 && o.rotate_mib <= 4096.0) {
            bail!(
                "outputs.rotate_mib: must be 0.001..=4096 (got {})",
                o.rotate_mib
            );
        }
        if o.transmit && o.transmit_interface.is_none() {
            bail!("outputs.transmit_interface: required when outputs.transmit = true");
        }
        if self.log.counters_interval_s == 0 {
            bail!("log.counters_interval_s: must be >= 1");
        }
        self.validate_mqtt()
    }

    /// The checks of the monitor's settings in effect ([`ObserverConfig::validate`]; keys named
    /// as in the daemon's file when they come from there, as in the monitor file otherwise).
    fn validate_settings(&self) -> anyhow::Result<()> {
        // `[observer.features]` in the daemon's file, `[features]` in the monitor file.
        let pre = if self.monitor.is_some() {
            ""
        } else {
            "observer."
        };
        self.settings.validate(pre)
    }

    /// Ranges are checked whether or not MQTT is enabled (a typo should not wait until the day
    /// it is switched on); host and client id are required only when enabled.
    fn validate_mqtt(&self) -> anyhow::Result<()> {
        let m = &self.mqtt;
        if m.enabled && m.host.trim().is_empty() {
            bail!("mqtt.host: required when mqtt.enabled = true");
        }
        if m.port == Some(0) {
            bail!("mqtt.port: must be 1..=65535");
        }
        let topic_safe = |s: &str| !s.is_empty() && !s.contains(['+', '#', '\0']);
        if (m.enabled || !m.client_id.is_empty())
            && (!topic_safe(&m.client_id) || m.client_id.contains('/') || m.client_id.len() > 64)
        {
            bail!(
                "mqtt.client_id: required when mqtt.enabled = true; 1-64 characters without '/', '+' or '#' (got \"{}\")",
                m.client_id
            );
        }
        if (m.enabled || !m.fleet.is_empty())
            && (!topic_safe(&m.fleet) || m.fleet.contains('/') || m.fleet.len() > 64)
        {
            bail!(
                "mqtt.fleet: required when mqtt.enabled = true; 1-64 characters without '/', '+' or '#' (got \"{}\")",
                m.fleet
            );
        }
        if m.estimate_expiry_s == 0 {
            bail!("mqtt.estimate_expiry_s: must be >= 1 (got 0)");
        }
        if !topic_safe(&m.topic_prefix)
            || m.topic_prefix.starts_with('/')
            || m.topic_prefix.ends_with('/')
        {
            bail!(
                "mqtt.topic_prefix: must be a topic without wildcards ('+', '#') or leading/trailing '/' (got \"{}\")",
                m.topic_prefix
            );
        }
        if m.qos > 2 {
            bail!("mqtt.qos: must be 0, 1 or 2 (got {})", m.qos);
        }
        if !(5..=3600).contains(&m.keep_alive_s) {
            bail!(
                "mqtt.keep_alive_s: must be 5..=3600 (got {})",
                m.keep_alive_s
            );
        }
        if !(m.reconnect_s.is_finite() && (0.05..=3600.0).contains(&m.reconnect_s)) {
            bail!(
                "mqtt.reconnect_s: must be 0.05..=3600 (got {})",
                m.reconnect_s
            );
        }
        if m.queue_max_messages == 0 || m.queue_max_messages > 1_000_000 {
            bail!(
                "mqtt.queue_max_messages: must be 1..=1000000 (got {})",
                m.queue_max_messages
            );
        }
        if !(m.queue_max_mib.is_finite() && (0.001..=1024.0).contains(&m.queue_max_mib)) {
            bail!(
                "mqtt.queue_max_mib: must be 0.001..=1024 (got {})",
                m.queue_max_mib
            );
        }
        if !(m.drain_timeout_s.is_finite() && (0.0..=600.0).contains(&m.drain_timeout_s)) {
            bail!(
                "mqtt.drain_timeout_s: must be 0..=600 (got {})",
                m.drain_timeout_s
            );
        }
        self.validate_mqtt_transport()
    }

    /// TLS or plain TCP: plain only when written; TLS needs the CA, and a client certificate
    /// comes with its key. What needs files (and that they exist) is checked when MQTT is
    /// enabled; contradictions always.
    fn validate_mqtt_transport(&self) -> anyhow::Result<()> {
        let m = &self.mqtt;
        if m.cert_file.is_some() != m.key_file.is_some() {
            bail!(
                "mqtt.cert_file and mqtt.key_file: give both (the client certificate and its private key) or neither"
            );
        }
        match m.transport() {
            None if m.enabled => bail!(
                "mqtt.transport: [mqtt] is enabled without TLS settings; give mqtt.ca_file (the CA \
                 that signed the broker's certificate, with mqtt.cert_file and mqtt.key_file for this \
                 vehicle's client certificate), or write transport = \"tcp\" to send to the broker \
                 in plain text, unencrypted and without authenticating it"
            ),
            None => {}
            Some(Transport::Tcp) => {
                for (key, p) in [
                    ("ca_file", &m.ca_file),
                    ("cert_file", &m.cert_file),
                    ("key_file", &m.key_file),
                ] {
                    if p.is_some() {
                        bail!(
                            "mqtt.{key}: given with transport = \"tcp\", which uses no TLS; remove one of them"
                        );
                    }
                }
            }
            Some(Transport::Tls) => {
                if m.enabled && m.ca_file.is_none() {
                    bail!(
                        "mqtt.ca_file: required with transport = \"tls\" (the CA the broker's certificate must chain to)"
                    );
                }
            }
        }
        if m.enabled {
            for (key, p) in [
                ("ca_file", &m.ca_file),
                ("cert_file", &m.cert_file),
                ("key_file", &m.key_file),
            ] {
                if let Some(p) = p {
                    if !p.is_file() {
                        bail!("mqtt.{key}: file {} does not exist", p.display());
                    }
                }
            }
        }
        Ok(())
    }

    /// The journal settings of `[outputs]`.
    pub fn journal(&self) -> JournalConfig {
        JournalConfig {
            fsync: match self.outputs.fsync.as_str() {
                "interval" => FsyncPolicy::IntervalMs(self.outputs.fsync_interval_ms),
                _ => FsyncPolicy::Always,
            },
            rotate_bytes: (self.outputs.rotate_mib * 1024.0 * 1024.0) as u64,
        }
    }
}
