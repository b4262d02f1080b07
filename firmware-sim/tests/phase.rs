//! The wheels' unbalance phase difference (MODEL.md §7) between braking events: kept for the
//! whole drive by default (the model's two wheels turn with one spin angle), drawn anew at
//! every stop with `phase_change = "per_stop"` (a turn at a junction). The ground-truth
//! sidecar records cos(φ_R − φ_L) of each event, and the option changes nothing else about
//! the drive.

use firmware_sim::bus::REFERENCE_DBC;
use firmware_sim::plant::ModelPlant;
use firmware_sim::truth::GroundTruth;
use firmware_sim::{FirmwareSim, RunInfo, Scenario};

fn drive(phase_change: &str) -> String {
    let mut s = format!(
        "seed = 11\n[clearance]\nleft_mm = 0.1\n[excitation]\nphase_change = \"{phase_change}\"\n\
         [drive]\nstart_speed_kmh = 40\naccel_g = 0.35\n"
    );
    for v in [40, 45, 50, 55] {
        s += &format!(
            "[[drive.segment]]\nkind = \"cruise\"\nspeed_kmh = {v}\nduration_s = 0.5\n\
             [[drive.segment]]\nkind = \"brake\"\ndecel_g = 0.6\nhold_s = 0.3\n"
        );
    }
    s
}

fn run(text: &str) -> GroundTruth {
    let sc = Scenario::parse(text, "test").unwrap();
    let plant = ModelPlant::new(&sc, None).unwrap();
    let mut sim = FirmwareSim::new(&sc, plant, REFERENCE_DBC, RunInfo::default()).unwrap();
    sim.run_to_end();
    sim.ground_truth()
}

fn phases(t: &GroundTruth) -> Vec<f64> {
    t.events
        .iter()
        .map(|e| e.unbalance_phase_cos.expect("the model plant has phases"))
        .collect()
}

#[test]
fn the_phase_difference_is_kept_unless_the_scenario_changes_it_at_stops() {
    let kept = run(&drive("none"));
    let changed = run(&drive("per_stop"));
    let (a, b) = (phases(&kept), phases(&changed));
    assert_eq!(a.len(), 4);
    assert_eq!(b.len(), 4);
    assert!(a.iter().all(|&x| x == a[0]), "kept: {a:?}");
    // The first event comes before any stop; each later one after a stop with a new draw.
    assert_eq!(a[0], b[0]);
    for w in b.windows(2) {
        assert!((w[1] - w[0]).abs() > 1e-6, "per stop: {b:?}");
    }
    // Only the steering response differs: the same drive, the same events (to the rounding
    // of the steering's tiny feedback on the longitudinal motion).
    for (x, y) in kept.events.iter().zip(&changed.events) {
        assert!((x.event.v0_kmh - y.event.v0_kmh).abs() < 1e-6);
        assert!((x.event.t_start_s - y.event.t_start_s).abs() < 1e-3);
    }
    assert_ne!(
        kept.events[3].sw_amplitude_deg,
        changed.events[3].sw_amplitude_deg
    );
    // Deterministic.
    assert_eq!(phases(&run(&drive("per_stop"))), b);
}

#[test]
fn an_unknown_phase_change_is_refused() {
    let e = Scenario::parse(&drive("per_turn"), "test").unwrap_err();
    assert!(format!("{e:#}").contains("per_turn"), "{e:#}");
}
