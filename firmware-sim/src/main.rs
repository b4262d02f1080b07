fn main() {
    eprintln!("firmware-sim: not implemented yet (issue 4)");
    std::process::exit(2);
}
