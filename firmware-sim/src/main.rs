//! The `firmware-sim` binary (the scenario and drive-cycle layers exist; the bus and outputs
//! follow once the DBC encoder and the model land).
fn main() {
    eprintln!("firmware-sim: not usable yet (issue 4): scenario and drive cycle only");
    std::process::exit(2);
}
