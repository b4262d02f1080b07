//! Vehicle profiles: the car as the unit a user deals with.
//!
//! A profile is one folder under `config/vehicles/<name>/` (the folder's name is the profile's
//! name) holding everything the monitor needs to know about one car model's bus and chassis:
//!
//! | file | what it is |
//! |---|---|
//! | `profile.toml` | names the DBC, the mapping, the table and the bus description; the chassis (MODEL.md §9) and its nuisance prior; the sensors as this car's bus carries them |
//! | `mapping.toml` | which DBC signals carry steering angle, speed, brake, acceleration ([`crate::signals::mapping`]) |
//! | `bus.toml` | the car's bus as it is on the road: message periods, counters, checksums, sign conventions ([`bus`]); firmware-sim emulates it and [`identify`] recognises it |
//! | `table.json` | the response table built for exactly this chassis and steering angle sensor (`shimmy calibrate --profile NAME`) |
//! | `table_torque*.json` | the EPS torque's tables: the chassis's own and one per `[[chassis.variants]]` entry (a structural alternative such as a scrub radius), among which each vehicle's events choose ([`Profile::load_torque_alternatives`]) |
//!
//! What this module is: the file format, the search path, and the checks that the parts fit
//! together (the table's chassis hash and sensor against the profile's). What it is not: the
//! decoding ([`crate::signals`]), the estimate ([`crate::observer`]) or the table build
//! (`shimmy calibrate`).
//!
//! Where profiles are looked up, first match wins: the directories in `SHIMMY_PROFILES`
//! (colon-separated), `./config/vehicles`, `/etc/shimmyd/vehicles`, and the `config/vehicles`
//! of the source tree the binary was built from. A path to a profile folder or to its
//! `profile.toml` is accepted wherever a name is.

pub mod bus;
pub mod identify;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use crate::model::VehicleParams;
use crate::observer::correction::CorrectionFile;
use crate::observer::sensor::SensorModel;
use crate::observer::simulate::{ColumnRanges, HandsPrior, NuisanceRanges};
use crate::observer::table::{vehicle_hash, ResponseTable};
use crate::signals::mapping::MappingConfig;

/// `profile.toml` as written.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileFile {
    /// The car's name as a person says it ("Toyota RAV4 2017").
    pub name: String,
    /// Other names `--profile` accepts (e.g. "rav4").
    #[serde(default)]
    pub aliases: Vec<String>,
    /// The DBC file: a path relative to the profile folder, or a file name looked up in the
    /// DBC search path ([`resolve_dbc`]).
    pub dbc: String,
    /// The signal mapping, relative to the profile folder.
    #[serde(default = "default_mapping")]
    pub mapping: String,
    /// The response table, relative to the profile folder. A profile without one still finds
    /// braking events and the shimmy-amplitude alert, but estimates no clearance.
    #[serde(default)]
    pub table: Option<String>,
    /// The response table of the EPS torsion-bar torque (`shimmy calibrate --signal torque`
    /// on this chassis with its MODEL.md §15 column enabled), relative to the profile folder.
    /// Where the bus carries a live torque the estimate comes from it (docs/ACCURACY.md: the
    /// rim angle under the driver's hands cannot decide a worn joint, the torque can); the
    /// angle table stays the fallback.
    #[serde(default)]
    pub torque_table: Option<String>,
    /// The car model's correction to its tables (`shimmy fleet-fit` over many of its vehicles
    /// at new joints; src/observer/correction.rs), relative to the profile folder. Each
    /// table whose signal has a section gets it, and every estimate from the profile applies
    /// it; a correction fitted against another table is refused.
    #[serde(default)]
    pub correction: Option<String>,
    /// The bus description (firmware-sim and `shimmy identify`), relative to the folder.
    #[serde(default)]
    pub bus: Option<String>,
    #[serde(default)]
    pub chassis: ChassisSection,
    #[serde(default)]
    pub sensors: SensorsSection,
}

fn default_mapping() -> String {
    "mapping.toml".into()
}

/// `[chassis]`: the shimmy model's parameters for this car and the prior the table puts
/// around them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChassisSection {
    /// A vehicle parameter file (MODEL.md §9 keys), relative to the profile folder; absent:
    /// MODEL.md §9's defaults.
    #[serde(default)]
    pub file: Option<String>,
    /// The nuisance prior around those values that the table integrates out; absent: the
    /// default (±10 % on k_s, c_s, k_t, k_g, c_g; unbalance ×0.5–2; road noise ×0.7–1.4).
    #[serde(default)]
    pub prior: Option<PriorSection>,
    /// `[[chassis.variants]]`: structural alternatives of this chassis that a car of the model
    /// may have and that the nuisance prior does not cover (a scrub radius turns the brake
    /// force into a steady kingpin moment, MODEL.md §14, which the nominal table would read as
    /// wear). Each names a torque table, an angle table or both, built on the chassis with that
    /// change; every estimate feeds all of the profile's tables of a signal and weighs their
    /// readings by how well the vehicle's events fit each ([`crate::observer::posterior`]).
    #[serde(default)]
    pub variants: Vec<ChassisVariant>,
}

/// One `[[chassis.variants]]` entry: the profile's chassis with one or more of its parameters
/// changed. At least one change is given.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChassisVariant {
    /// How reports name it ("scrub radius 10 mm").
    pub name: String,
    /// The kingpin's scrub radius r_s of this variant (mm; MODEL.md §9 `scrub_radius_m`);
    /// absent: the chassis's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scrub_radius_mm: Option<f64>,
    /// The variant's kingpin damping c_s as a multiple of the chassis's (MODEL.md §9
    /// `kingpin_damping_nms_per_rad`); absent: 1. The rattle's onset hangs on c_s (a threshold,
    /// src/observer/linear.rs), so a car whose damping sits beyond the prior's ±10 % is read as
    /// far too worn or far too tight by the nominal table.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kingpin_damping_scale: Option<f64>,
    /// Uneven front brake discs (a disc thickness variation, MODEL.md §14): each disc's
    /// brake-torque variation ε, relative to the brake force, lies in `[low, high]` and its
    /// thickest point anywhere on the wheel; the variant's table draws both per table vehicle
    /// (`shimmy calibrate --brake-torque-variation-rel LOW,HIGH`). Through a scrub radius the
    /// variation shakes the steering at wheel order while braking whatever the joints, which
    /// the nominal table reads as wear. Absent: even discs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub brake_torque_variation_rel: Option<[f64; 2]>,
    /// What a workshop should check on a car read with this variant ("the wheels' offset
    /// (non-standard wheels or spacers change the scrub radius)"); absent: nothing, the
    /// variant is a property of the car model, not a fault.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inspect: Option<String>,
    /// Its torque table (`shimmy calibrate --signal torque` on the chassis with this change
    /// and the §15 column), relative to the profile folder; needs the profile's own
    /// `torque_table`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub torque_table: Option<String>,
    /// Its steering-angle table (`shimmy calibrate` on the chassis with this change, for the
    /// profile's angle sensor), relative to the profile folder; needs the profile's own
    /// `table`. At least one of the two tables is given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub table: Option<String>,
    /// The probability that a car of this model has this variant rather than the profile's
    /// chassis, before any of its events is seen; default [`DEFAULT_VARIANT_PRIOR`]. A vehicle
    /// is read with the variant's table once its events favour it by more than these odds.
    #[serde(default = "default_variant_prior")]
    pub prior_probability: f64,
}

impl ChassisVariant {
    /// Its own fields: at least one change, each in range, and a prior probability in (0, 1).
    /// What concerns the profile (unique names, the nominal torque table beside it, the
    /// priors' sum) the profile checks.
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.scrub_radius_mm.is_none()
            && self.kingpin_damping_scale.is_none()
            && self.brake_torque_variation_rel.is_none()
        {
            bail!(
                "changes nothing: give scrub_radius_mm, kingpin_damping_scale or \
                 brake_torque_variation_rel"
            );
        }
        if let Some([lo, hi]) = self.brake_torque_variation_rel {
            crate::observer::simulate::check_brake_torque_variation(
                "brake_torque_variation_rel",
                (lo, hi),
            )?;
        }
        if let Some(r) = self.scrub_radius_mm {
            if !(r.is_finite() && (0.0..=50.0).contains(&r)) {
                bail!("scrub_radius_mm must be 0 to 50 mm (got {r})");
            }
        }
        if let Some(k) = self.kingpin_damping_scale {
            if !(k.is_finite() && (0.2..=5.0).contains(&k)) {
                bail!("kingpin_damping_scale must be 0.2 to 5 (got {k})");
            }
        }
        let p = self.prior_probability;
        if !(p > 0.0 && p < 1.0) {
            bail!("prior_probability must be between 0 and 1 (got {p})");
        }
        Ok(())
    }
}

/// The prior probability of a chassis variant when its entry gives none: the profile's own
/// chassis stays the expected one (docs/ACCURACY.md, "Chassis variants", measures the choice).
pub const DEFAULT_VARIANT_PRIOR: f64 = 0.2;

fn default_variant_prior() -> f64 {
    DEFAULT_VARIANT_PRIOR
}

/// Whether two paths name the same file (compared as written where either cannot be resolved).
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

/// Which steering signal's table a chassis variant's entry names.
#[derive(Clone, Copy)]
enum Signal {
    Angle,
    Torque,
}

/// `[chassis.prior]` ([`NuisanceRanges`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PriorSection {
    /// Relative ± spread of each steering stiffness and damping (0.1 = ±10 %).
    pub stiffness_damping_rel: f64,
    /// Unbalance factor range (log-uniform).
    pub unbalance_factor: [f64; 2],
    /// Road-noise factor range (uniform).
    pub road_noise_factor: [f64; 2],
    /// `[chassis.prior.column]`: ranges of J_sw, k_tb, c_tb drawn per vehicle when the chassis
    /// has the MODEL.md §15 column; absent: docs/COLUMN.md's published ranges.
    #[serde(default)]
    pub column: Option<ColumnRanges>,
    /// `[chassis.prior.hands]`: the driver's hands per braking event (off / light / firm);
    /// absent: docs/COLUMN.md's defaults.
    #[serde(default)]
    pub hands: Option<HandsPrior>,
}

impl From<PriorSection> for NuisanceRanges {
    fn from(p: PriorSection) -> NuisanceRanges {
        let d = NuisanceRanges::default();
        NuisanceRanges {
            stiffness_damping_rel: p.stiffness_damping_rel,
            unbalance_factor: (p.unbalance_factor[0], p.unbalance_factor[1]),
            road_noise_factor: (p.road_noise_factor[0], p.road_noise_factor[1]),
            column: p.column.or(d.column),
            hands: p.hands.or(d.hands),
            brake_torque_variation_rel: None,
        }
    }
}

/// `[sensors]`: what this car's bus carries, as measured on it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorsSection {
    /// The steering angle sensor (rate, step, noise; [`SensorModel`]). Absent: the reference
    /// bus's 100 Hz, 0.1° sensor.
    #[serde(default)]
    pub steer_angle: Option<SensorModel>,
    /// The EPS torsion-bar torque, where the bus carries it (MODEL.md §15 T_c).
    #[serde(default)]
    pub steer_torque: Option<TorqueSensor>,
}

/// A steering torque signal on the bus (its step is the DBC signal's factor).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TorqueSensor {
    pub message: String,
    pub signal: String,
    /// Sample rate (Hz) on the bus.
    pub rate_hz: f64,
    /// N·m per unit of the DBC's physical value, where known (VW: 0.01, the DBC counts
    /// centi-N·m); absent where the car's scale is not public (the signal is then in counts).
    #[serde(default)]
    pub nm_per_unit: Option<f64>,
}

/// A profile resolved from its folder: every path checked, the mapping and chassis loaded.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    /// The folder's name.
    pub name: String,
    pub dir: PathBuf,
    pub file: ProfileFile,
    pub dbc_path: PathBuf,
    pub mapping_path: PathBuf,
    pub mapping: MappingConfig,
    pub vehicle: VehicleParams,
    /// Where the chassis came from (a file, or "MODEL.md §9 defaults").
    pub vehicle_source: String,
    pub prior: NuisanceRanges,
    pub sensor: SensorModel,
    pub table_path: Option<PathBuf>,
    pub torque_table_path: Option<PathBuf>,
    pub correction_path: Option<PathBuf>,
    pub bus_path: Option<PathBuf>,
}

/// The directories searched for profiles, in order (see the module docs).
pub fn search_dirs() -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    if let Some(v) = std::env::var_os("SHIMMY_PROFILES") {
        dirs.extend(std::env::split_paths(&v).filter(|p| !p.as_os_str().is_empty()));
    }
    dirs.push(PathBuf::from("config/vehicles"));
    dirs.push(PathBuf::from("/etc/shimmyd/vehicles"));
    dirs.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/vehicles"));
    dirs
}

/// Every profile folder found on the search path, by name (the first of each name wins), in
/// name order.
pub fn list() -> Vec<PathBuf> {
    let mut found: std::collections::BTreeMap<String, PathBuf> = Default::default();
    for dir in search_dirs() {
        let Ok(rd) = std::fs::read_dir(&dir) else {
            continue;
        };
        for e in rd.flatten() {
            let p = e.path();
            if p.join("profile.toml").is_file() {
                if let Some(n) = p.file_name().and_then(|n| n.to_str()) {
                    found.entry(n.to_string()).or_insert(p);
                }
            }
        }
    }
    found.into_values().collect()
}

/// Loads every profile on the search path; a profile that fails to load is returned as the
/// error with its folder named.
pub fn load_all() -> Vec<anyhow::Result<Profile>> {
    list().into_iter().map(|d| Profile::load_dir(&d)).collect()
}

/// Finds a profile folder by name, alias, folder path or `profile.toml` path.
pub fn find(name: &str) -> anyhow::Result<PathBuf> {
    find_in(name, &[])
}

/// [`find`], looking in `first` (directories holding profile folders) before the search path.
pub fn find_in(name: &str, first: &[PathBuf]) -> anyhow::Result<PathBuf> {
    let p = Path::new(name);
    if p.file_name().is_some_and(|f| f == "profile.toml") && p.is_file() {
        return Ok(p.parent().unwrap_or(Path::new(".")).to_path_buf());
    }
    if p.join("profile.toml").is_file() && (name.contains('/') || name.starts_with('.')) {
        return Ok(p.to_path_buf());
    }
    for dir in first.iter().cloned().chain(search_dirs()) {
        let cand = dir.join(name);
        if cand.join("profile.toml").is_file() {
            return Ok(cand);
        }
    }
    let mut names = Vec::new();
    for d in list() {
        if let Ok(f) = read_file(&d) {
            if f.aliases.iter().any(|a| a.eq_ignore_ascii_case(name)) {
                return Ok(d);
            }
        }
        if let Some(n) = d.file_name().and_then(|n| n.to_str()) {
            names.push(n.to_string());
        }
    }
    bail!(
        "no vehicle profile `{name}` (known: {}; searched {})",
        if names.is_empty() {
            "none".to_string()
        } else {
            names.join(", ")
        },
        search_dirs()
            .iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )
}

fn read_file(dir: &Path) -> anyhow::Result<ProfileFile> {
    let path = dir.join("profile.toml");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    toml::from_str(&text).with_context(|| format!("in {}", path.display()))
}

/// Finds a DBC named `name` (a path relative to `base`, or a bare file name): `base`, the
/// repository's `dbc/`, `./dbc`, `SHIMMY_DBC_PATH` (colon-separated), the shared data's
/// `dbc/opendbc` and `dbc`.
pub fn resolve_dbc(base: &Path, name: &str) -> anyhow::Result<PathBuf> {
    let mut cands = vec![
        base.join(name),
        base.join("../../../dbc").join(name),
        PathBuf::from("dbc").join(name),
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("dbc")
            .join(name),
    ];
    if let Some(v) = std::env::var_os("SHIMMY_DBC_PATH") {
        cands.extend(std::env::split_paths(&v).map(|d| d.join(name)));
    }
    let data = crate::shared_data::configured_dir();
    cands.push(data.join("dbc/opendbc").join(name));
    cands.push(data.join("dbc").join(name));
    for c in &cands {
        if c.is_file() {
            return Ok(c.clone());
        }
    }
    bail!(
        "DBC `{name}` not found (tried {}); set SHIMMY_DBC_PATH to the folder that holds it",
        cands
            .iter()
            .map(|c| c.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )
}

impl Profile {
    /// Loads the profile `name` (see [`find`]).
    pub fn load(name: &str) -> anyhow::Result<Profile> {
        let dir = find(name)?;
        Profile::load_dir(&dir)
    }

    /// Loads the profile in folder `dir`.
    pub fn load_dir(dir: &Path) -> anyhow::Result<Profile> {
        let file = read_file(dir)?;
        let name = dir
            .canonicalize()
            .unwrap_or_else(|_| dir.to_path_buf())
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("profile")
            .to_string();
        let ctx = || format!("vehicle profile {}", dir.display());
        let dbc_path = resolve_dbc(dir, &file.dbc).with_context(ctx)?;
        let mapping_path = dir.join(&file.mapping);
        let mapping = MappingConfig::from_toml_file(&mapping_path)
            .with_context(|| format!("mapping {}", mapping_path.display()))
            .with_context(ctx)?;
        let (vehicle, vehicle_source) = match &file.chassis.file {
            Some(f) => {
                let p = dir.join(f);
                let v = VehicleParams::from_toml_file(&p)
                    .with_context(|| format!("chassis {}", p.display()))
                    .with_context(ctx)?;
                (v, p.display().to_string())
            }
            None => (VehicleParams::default(), "MODEL.md §9 defaults".into()),
        };
        let prior = file
            .chassis
            .prior
            .map(NuisanceRanges::from)
            .unwrap_or_default();
        check_prior(&prior).with_context(ctx)?;
        let sensor = file.sensors.steer_angle.unwrap_or_default();
        sensor
            .validate()
            .context("sensors.steer_angle")
            .with_context(ctx)?;
        let total: f64 = file
            .chassis
            .variants
            .iter()
            .map(|v| v.prior_probability)
            .sum();
        if total >= 1.0 {
            bail!(
                "{}: the chassis variants' prior probabilities add up to {total}: they must \
                 leave the profile's own chassis some",
                ctx()
            );
        }
        let mut names = std::collections::HashSet::new();
        for v in &file.chassis.variants {
            v.validate()
                .with_context(|| format!("{}: chassis variant `{}`", ctx(), v.name))?;
            if v.name.trim().is_empty()
                || v.name == crate::observer::NOMINAL_TABLE
                || !names.insert(v.name.as_str())
            {
                bail!(
                    "{}: chassis variant names must be unique, not empty and not `{}` (got `{}`)",
                    ctx(),
                    crate::observer::NOMINAL_TABLE,
                    v.name
                );
            }
            if v.torque_table.is_none() && v.table.is_none() {
                bail!(
                    "{}: chassis variant `{}` names no table: give its torque_table, its \
                     (angle) table or both",
                    ctx(),
                    v.name
                );
            }
            if v.torque_table.is_some() && file.torque_table.is_none() {
                bail!(
                    "{}: chassis variant `{}` needs the nominal torque_table beside it",
                    ctx(),
                    v.name
                );
            }
            if v.table.is_some() && file.table.is_none() {
                bail!(
                    "{}: chassis variant `{}` needs the nominal (angle) table beside it",
                    ctx(),
                    v.name
                );
            }
        }
        let opt = |f: &Option<String>| f.as_ref().map(|f| dir.join(f));
        let table_path = opt(&file.table);
        let torque_table_path = opt(&file.torque_table);
        let correction_path = opt(&file.correction);
        let bus_path = opt(&file.bus);
        for (key, p) in [("bus", &bus_path)] {
            if let Some(p) = p {
                if !p.is_file() {
                    bail!("{}: {key} file {} does not exist", ctx(), p.display());
                }
            }
        }
        Ok(Profile {
            name,
            dir: dir.to_path_buf(),
            dbc_path,
            mapping_path,
            mapping,
            vehicle,
            vehicle_source,
            prior,
            sensor,
            table_path,
            torque_table_path,
            correction_path,
            bus_path,
            file,
        })
    }

    /// "toyota_rav4 (Toyota RAV4 2017)".
    pub fn label(&self) -> String {
        format!("{} ({})", self.name, self.file.name)
    }

    /// The hash a table built for this profile's chassis records.
    pub fn chassis_hash(&self) -> anyhow::Result<String> {
        vehicle_hash(&self.vehicle)
    }

    /// The profile's response table, checked against its chassis and steering angle sensor.
    /// `Ok(None)` when the profile names no table.
    pub fn load_table(&self) -> anyhow::Result<Option<ResponseTable>> {
        let Some(path) = &self.table_path else {
            return Ok(None);
        };
        if !path.is_file() {
            bail!(
                "profile {}: its table {} does not exist; build it with `shimmy calibrate \
                 --profile {}`",
                self.name,
                path.display(),
                self.name
            );
        }
        let t = ResponseTable::load(path)?;
        self.check_table(&t)
            .with_context(|| format!("profile {}: table {}", self.name, path.display()))?;
        Ok(Some(self.corrected(t)?))
    }

    /// The profile's torque table ([`ProfileFile::torque_table`]), checked: a table of the
    /// torque, built on this chassis with its §15 column enabled, with the profile's prior, at the rate the
    /// profile's `[sensors.steer_torque]` gives. `Ok(None)` when the profile names none, or
    /// when its mapping maps no steering torque (nothing would feed it).
    pub fn load_torque_table(&self) -> anyhow::Result<Option<ResponseTable>> {
        let Some(path) = &self.torque_table_path else {
            return Ok(None);
        };
        if self.mapping.steer_torque.is_none() {
            return Ok(None);
        }
        let ctx = || format!("profile {}: torque table {}", self.name, path.display());
        let t = ResponseTable::load(path).with_context(ctx)?;
        self.check_torque_table(&t).with_context(ctx)?;
        Ok(Some(self.corrected(t)?))
    }

    /// The chassis of a variant: the profile's with the variant's change.
    pub fn variant_vehicle(&self, v: &ChassisVariant) -> VehicleParams {
        let mut p = self.vehicle.clone();
        if let Some(r) = v.scrub_radius_mm {
            p.steering.scrub_radius_m = r / 1000.0;
        }
        if let Some(k) = v.kingpin_damping_scale {
            p.steering.kingpin_damping_nms_per_rad *= k;
        }
        p
    }

    /// The nuisance prior of a variant's table: the profile's, with the variant's brake discs
    /// drawn per table vehicle where it has uneven ones.
    pub fn variant_prior(&self, v: &ChassisVariant) -> NuisanceRanges {
        NuisanceRanges {
            brake_torque_variation_rel: v.brake_torque_variation_rel.map(|[lo, hi]| (lo, hi)),
            ..self.prior
        }
    }

    /// The torque tables of the profile's `[[chassis.variants]]`, by name, each checked as
    /// [`Self::check_torque_table`] checks the nominal one but against its variant's chassis,
    /// to go beside `nominal`, the profile's torque table as [`Self::load_torque_table`] gave
    /// it, or as read from `read_from` (`None`: the profile's own file). Empty when the profile
    /// has no variants, names no torque table or maps no torque, and when `read_from` is another
    /// file than the profile's torque table: the variants are the alternatives of the profile's
    /// own table, not of one given in its place.
    ///
    /// The correction `nominal` carries (the profile's, checked against the table it was
    /// fitted on) is applied to every variant's table too: its gains describe the car's signal
    /// path (sensor scale, column transfer), which a scrub radius does not change, and the
    /// tables' evidence compares only on the same corrected features.
    pub fn load_torque_alternatives(
        &self,
        nominal: &ResponseTable,
        read_from: Option<&Path>,
    ) -> anyhow::Result<Vec<crate::observer::Alternative>> {
        if self.mapping.steer_torque.is_none() {
            return Ok(Vec::new());
        }
        self.load_alternatives(nominal, read_from, Signal::Torque)
    }

    /// The angle tables of the profile's `[[chassis.variants]]` that name one, by name, each
    /// checked as [`Self::check_table`] checks the nominal one but against its variant's
    /// chassis and prior, to go beside `nominal`, the profile's angle table as
    /// [`Self::load_table`] gave it or as read from `read_from` (`None`: the profile's own
    /// file; its correction, when it has one, applies to them too, as
    /// [`Self::load_torque_alternatives`] says). Empty when no variant names an angle table,
    /// and when `read_from` is another file than the profile's angle table.
    pub fn load_angle_alternatives(
        &self,
        nominal: &ResponseTable,
        read_from: Option<&Path>,
    ) -> anyhow::Result<Vec<crate::observer::Alternative>> {
        self.load_alternatives(nominal, read_from, Signal::Angle)
    }

    /// Whether `path` is one of the profile's own tables, its angle or its torque table (the
    /// same file): a table given in its place is another table, which neither the profile's
    /// correction nor its chassis variants describe.
    pub fn is_own_table(&self, path: &Path) -> bool {
        [&self.table_path, &self.torque_table_path]
            .into_iter()
            .any(|own| own.as_deref().is_some_and(|o| same_file(o, path)))
    }

    /// The variants' tables of `signal`, each checked against its variant's chassis and prior
    /// and given `nominal`'s correction.
    fn load_alternatives(
        &self,
        nominal: &ResponseTable,
        read_from: Option<&Path>,
        signal: Signal,
    ) -> anyhow::Result<Vec<crate::observer::Alternative>> {
        let own = match signal {
            Signal::Angle => &self.table_path,
            Signal::Torque => &self.torque_table_path,
        };
        let Some(own) = own else {
            return Ok(Vec::new());
        };
        if read_from.is_some_and(|p| !same_file(own, p)) {
            return Ok(Vec::new());
        }
        let mut out = Vec::new();
        for v in &self.file.chassis.variants {
            let (file, what) = match signal {
                Signal::Angle => (&v.table, "table"),
                Signal::Torque => (&v.torque_table, "torque table"),
            };
            let Some(file) = file else {
                continue;
            };
            let path = self.dir.join(file);
            let ctx = || {
                format!(
                    "profile {}: chassis variant `{}`: {what} {}",
                    self.name,
                    v.name,
                    path.display()
                )
            };
            let mut t = ResponseTable::load(&path).with_context(ctx)?;
            let (vehicle, prior) = (self.variant_vehicle(v), self.variant_prior(v));
            match signal {
                Signal::Angle => self.check_table_on(&t, &vehicle, &prior),
                Signal::Torque => self.check_torque_table_on(&t, &vehicle, &prior),
            }
            .with_context(ctx)?;
            t.correction = nominal.correction.clone();
            out.push(crate::observer::Alternative {
                name: v.name.clone(),
                prior: v.prior_probability,
                inspect: v.inspect.clone(),
                table: t,
            });
        }
        Ok(out)
    }

    /// The profile's correction ([`ProfileFile::correction`]), `None` when it names none.
    pub fn load_correction(&self) -> anyhow::Result<Option<CorrectionFile>> {
        match &self.correction_path {
            Some(p) => Ok(Some(
                CorrectionFile::load(p).with_context(|| format!("profile {}", self.name))?,
            )),
            None => Ok(None),
        }
    }

    /// `t` with the profile's correction of its signal attached, when there is one; refused
    /// when it was fitted against another table. [`Self::load_table`] and
    /// [`Self::load_torque_table`] apply it; a caller that loads the profile's table from its
    /// path itself (shimmyd) calls it.
    pub fn corrected(&self, mut t: ResponseTable) -> anyhow::Result<ResponseTable> {
        let Some(file) = self.load_correction()? else {
            return Ok(t);
        };
        if let Some(c) = file.of(t.sensor.signal) {
            if c.table_fingerprint != t.fingerprint {
                bail!(
                    "profile {}: its correction {} was fitted against another {} table (fingerprint \
                     {}, this table's {}); fit it again with `shimmy fleet-fit`",
                    self.name,
                    self.correction_path.as_deref().unwrap_or(Path::new("?")).display(),
                    if t.sensor.signal.is_angle() { "steering-angle" } else { "torque" },
                    c.table_fingerprint,
                    t.fingerprint
                );
            }
            t.correction = Some(c.clone());
        }
        Ok(t)
    }

    /// Refuses a torque table built for another chassis, prior or torque rate.
    pub fn check_torque_table(&self, t: &ResponseTable) -> anyhow::Result<()> {
        self.check_torque_table_on(t, &self.vehicle, &self.prior)
    }

    /// [`Self::check_torque_table`] against `vehicle` (the profile's, or a variant's).
    fn check_torque_table_on(
        &self,
        t: &ResponseTable,
        vehicle: &VehicleParams,
        prior: &NuisanceRanges,
    ) -> anyhow::Result<()> {
        t.check_torque_vehicle(vehicle)?;
        if let Some(ts) = &self.file.sensors.steer_torque {
            if (t.sensor.rate_hz - ts.rate_hz).abs() > 0.05 * ts.rate_hz {
                bail!(
                    "built for a torque sensor of {} Hz, but the profile's sends at {} Hz",
                    t.sensor.rate_hz,
                    ts.rate_hz
                );
            }
        }
        if t.prior != *prior {
            bail!(
                "built with the nuisance prior {:?}, but the profile's is {:?}",
                t.prior,
                prior
            );
        }
        Ok(())
    }

    /// Refuses a table built for another chassis or sensor than this profile's.
    pub fn check_table(&self, t: &ResponseTable) -> anyhow::Result<()> {
        self.check_table_on(t, &self.vehicle, &self.prior)
    }

    /// [`Self::check_table`] against `vehicle` and `prior` (the profile's, or a variant's).
    fn check_table_on(
        &self,
        t: &ResponseTable,
        vehicle: &VehicleParams,
        prior: &NuisanceRanges,
    ) -> anyhow::Result<()> {
        t.check_vehicle(&vehicle_hash(vehicle)?)?;
        if t.sensor != self.sensor {
            bail!(
                "built for a steering angle sensor of {} Hz, {} deg steps, {} deg noise, but the \
                 profile's is {} Hz, {} deg, {} deg; rebuild it with `shimmy calibrate --profile {}`",
                t.sensor.rate_hz,
                t.sensor.step_deg,
                t.sensor.noise_deg,
                self.sensor.rate_hz,
                self.sensor.step_deg,
                self.sensor.noise_deg,
                self.name
            );
        }
        if t.prior != *prior {
            bail!(
                "built with the nuisance prior {:?}, but the profile's is {:?}; rebuild it with \
                 `shimmy calibrate --profile {}`",
                t.prior,
                prior,
                self.name
            );
        }
        Ok(())
    }

    /// The bus description, when the profile has one.
    pub fn load_bus(&self) -> anyhow::Result<Option<bus::BusSpec>> {
        match &self.bus_path {
            Some(p) => Ok(Some(bus::BusSpec::load(p)?)),
            None => Ok(None),
        }
    }
}

/// Rejects nuisance priors the table builder cannot draw from.
pub fn check_prior(r: &NuisanceRanges) -> anyhow::Result<()> {
    let ok = |lo: f64, hi: f64| lo.is_finite() && hi.is_finite() && lo > 0.0 && hi >= lo;
    if !(r.stiffness_damping_rel.is_finite() && (0.0..0.9).contains(&r.stiffness_damping_rel)) {
        bail!(
            "chassis.prior.stiffness_damping_rel: must be 0 to 0.9 (got {})",
            r.stiffness_damping_rel
        );
    }
    if !ok(r.unbalance_factor.0, r.unbalance_factor.1) {
        bail!(
            "chassis.prior.unbalance_factor: must be [low, high] with 0 < low <= high (got {:?})",
            r.unbalance_factor
        );
    }
    if !ok(r.road_noise_factor.0, r.road_noise_factor.1) {
        bail!(
            "chassis.prior.road_noise_factor: must be [low, high] with 0 < low <= high (got {:?})",
            r.road_noise_factor
        );
    }
    if let Some(c) = &r.column {
        c.validate().context("chassis.prior")?;
    }
    if let Some(h) = &r.hands {
        h.validate().context("chassis.prior")?;
    }
    if let Some(b) = r.brake_torque_variation_rel {
        crate::observer::simulate::check_brake_torque_variation("brake_torque_variation_rel", b)?;
    }
    Ok(())
}
