//! The Debian package (config/debian/build.sh, docs/GATEWAY.md): built once with the shipping
//! profile `dist`, then
//! - its contents: exactly the expected files, root-owned, with sane modes; its control data,
//!   conffiles and maintainer scripts (`sh -n`);
//! - unpacked (`dpkg-deb -x`) into a temporary root: the packaged `shimmyd --check` passes on
//!   the packaged configuration with every packaged profile, using the packaged profile and DBC
//!   (the output names them; the shared data is hidden);
//! - the unit: `systemd-analyze verify` clean, `systemd-analyze security --offline=true`
//!   exposure ≤ 2.0 alone and with the MQTT drop-in that the packaged generator writes for a
//!   configuration with `[mqtt] enabled = true` (and nothing for one without); the sandbox
//!   check of `shimmyd --check` against a stale drop-in;
//! - installed for real, only as root under CI=true (CI's fresh Debian machine) or with
//!   SHIMMY_DEB_INSTALL=1: `dpkg -i`, the user, /var/lib/shimmyd and the enablement, the
//!   installed unit verified and measured, `shimmyd --check` on /etc/shimmyd/shimmyd.toml;
//!   `dpkg -r` keeps the configuration and the journal, `dpkg --purge` leaves nothing behind.
//!   Elsewhere that test says SKIPPED: the maintainer scripts create a system user, and running
//!   them against a fake root would test the fake.
//!
//! Without the shared data (the opendbc DBCs the car profiles carry), dpkg-deb, readelf or
//! systemd-analyze the tests print SKIPPED and pass, except under CI=true, where they fail.
//!
//! `systemd-analyze verify` needs the unit's programs at their paths and systemd's own units
//! beside it; in the unpacked root it checks a copy of the unit whose /usr/bin and /etc/shimmyd
//! paths point into that root (the real install checks the installed unit as it is).
//! Offline `security` reads no generator directory, so the generated drop-in is measured from
//! the unpacked root's /etc/systemd/system/shimmyd.service.d/.

#[path = "support/outside_cargo.rs"]
mod outside_cargo;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::Mutex;

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn in_ci() -> bool {
    shimmy::shared_data::in_ci()
}

/// SKIPPED notice, or a failure under CI=true.
fn skip(why: &str) {
    if in_ci() {
        panic!("{why}; required under CI=true");
    }
    eprintln!("SKIPPED: {why}");
}

/// `name` on PATH or in the sbin directories.
fn tool(name: &str) -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).collect())
        .unwrap_or_default();
    dirs.extend(["/usr/sbin", "/sbin", "/usr/bin"].map(PathBuf::from));
    dirs.iter().map(|d| d.join(name)).find(|p| p.is_file())
}

/// The tools every test here needs, or a skip.
fn tools() -> bool {
    let missing: Vec<&str> = ["dpkg", "dpkg-deb", "readelf", "systemd-analyze", "bash"]
        .into_iter()
        .filter(|t| tool(t).is_none())
        .collect();
    if missing.is_empty() {
        return true;
    }
    skip(&format!(
        "{} not found (Debian: apt-get install dpkg binutils systemd)",
        missing.join(", ")
    ));
    false
}

fn run(cmd: &mut Command) -> Output {
    cmd.output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"))
}

/// Runs `cmd`, panics with its output unless it succeeds; returns stdout + stderr.
fn ok(cmd: &mut Command) -> String {
    let out = run(cmd);
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{text}",
        out.status
    );
    text
}

/// The package, built once for all tests of this file (`None`: skipped).
fn package() -> Option<PathBuf> {
    static BUILT: Mutex<Option<Result<PathBuf, String>>> = Mutex::new(None);
    if !tools() {
        return None;
    }
    let data = shimmy::shared_data::require("the car profiles' DBCs (dbc/opendbc)")?;
    let mut built = BUILT.lock().unwrap_or_else(|e| e.into_inner());
    let result = built.get_or_insert_with(|| {
        let t0 = std::time::Instant::now();
        let out = run(outside_cargo::outside_cargo(Command::new("bash"))
            .arg(workspace().join("config/debian/build.sh"))
            .env("SHIMMY_DATA_DIR", &data)
            .env_remove("SHIMMY_DBC_PATH")
            .current_dir(workspace()));
        if !out.status.success() {
            return Err(format!(
                "config/debian/build.sh failed ({}):\n{}{}",
                out.status,
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            ));
        }
        let stdout = String::from_utf8_lossy(&out.stdout);
        let deb = PathBuf::from(stdout.lines().last().unwrap_or("").trim());
        let size = std::fs::metadata(&deb).map(|m| m.len()).unwrap_or(0);
        eprintln!(
            "built {} ({size} B) in {:.0} s",
            deb.display(),
            t0.elapsed().as_secs_f64()
        );
        if size == 0 {
            return Err(format!(
                "build.sh printed {}, which is no file",
                deb.display()
            ));
        }
        Ok(deb)
    });
    match result {
        Ok(p) => Some(p.clone()),
        Err(e) => panic!("{e}"),
    }
}

/// The profiles of the source tree: (name, the files of its folder, its DBC's file name).
fn profiles() -> Vec<(String, Vec<String>, String)> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(workspace().join("config/vehicles")).unwrap() {
        let dir = e.unwrap().path();
        let Ok(text) = std::fs::read_to_string(dir.join("profile.toml")) else {
            continue;
        };
        let file: toml::Table = toml::from_str(&text).unwrap();
        let dbc = file["dbc"].as_str().unwrap().to_string();
        let mut files: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|f| f.unwrap())
            .filter(|f| f.path().is_file())
            .map(|f| f.file_name().to_string_lossy().into_owned())
            .collect();
        files.sort();
        v.push((
            dir.file_name().unwrap().to_string_lossy().into_owned(),
            files,
            dbc,
        ));
    }
    v.sort();
    assert!(v.len() >= 5, "expected the five profiles, found {v:?}");
    v
}

/// Every file and directory the package must hold, with its `ls -l` mode.
fn expected_entries() -> BTreeMap<String, &'static str> {
    const DIR: &str = "drwxr-xr-x";
    const EXE: &str = "-rwxr-xr-x";
    const DATA: &str = "-rw-r--r--";
    let mut m = BTreeMap::new();
    for (p, mode) in [
        ("usr/bin/shimmyd", EXE),
        ("usr/bin/shimmy", EXE),
        ("usr/lib/systemd/system/shimmyd.service", DATA),
        (
            "usr/lib/systemd/system-generators/shimmyd-sandbox-generator",
            EXE,
        ),
        ("etc/shimmyd/shimmyd.toml", DATA),
        ("etc/shimmyd/observer.toml", DATA),
        ("usr/share/doc/shimmy-monitor/copyright", DATA),
    ] {
        m.insert(p.to_string(), mode);
    }
    for (name, files, dbc) in profiles() {
        for f in files.iter().chain([&dbc]) {
            m.insert(format!("etc/shimmyd/vehicles/{name}/{f}"), DATA);
        }
    }
    let dirs: Vec<String> = m
        .keys()
        .flat_map(|p| {
            let mut d = Vec::new();
            let mut q = Path::new(p).parent();
            while let Some(x) = q.filter(|x| !x.as_os_str().is_empty()) {
                d.push(x.to_string_lossy().into_owned());
                q = x.parent();
            }
            d
        })
        .collect();
    for d in dirs {
        m.insert(d, DIR);
    }
    m
}

#[test]
fn contents_modes_control_and_maintainer_scripts() {
    let Some(deb) = package() else { return };
    let listing = ok(Command::new("dpkg-deb").arg("-c").arg(&deb));
    let mut found = BTreeMap::new();
    for line in listing.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        assert!(f.len() >= 6, "unexpected dpkg-deb -c line: {line}");
        assert_eq!(f[1], "root/root", "not root-owned: {line}");
        let path = f[5].trim_start_matches("./").trim_end_matches('/');
        if path.is_empty() {
            continue;
        }
        assert!(f.len() == 6, "link or odd name in the package: {line}");
        found.insert(path.to_string(), f[0].to_string());
    }
    let expected = expected_entries();
    for (p, mode) in &expected {
        match found.get(p) {
            None => panic!("{p} missing from the package; it holds:\n{listing}"),
            Some(m) => assert_eq!(m, mode, "mode of {p}"),
        }
    }
    let extra: Vec<&String> = found
        .keys()
        .filter(|p| !expected.contains_key(*p))
        .collect();
    assert!(
        extra.is_empty(),
        "unexpected files in the package: {extra:?}"
    );

    let info = ok(Command::new("dpkg-deb").arg("-I").arg(&deb));
    let field = |name: &str| {
        info.lines()
            .find_map(|l| l.trim().strip_prefix(&format!("{name}: ")))
            .unwrap_or_else(|| panic!("no {name} in the control file:\n{info}"))
            .to_string()
    };
    assert_eq!(field("Package"), "shimmy-monitor");
    assert_eq!(field("Version"), env!("CARGO_PKG_VERSION"));
    let arch = ok(Command::new("dpkg").arg("--print-architecture"));
    assert_eq!(field("Architecture"), arch.trim());
    let depends = field("Depends");
    assert!(
        depends.contains("libc6 (>= 2.") && depends.contains("passwd"),
        "Depends: {depends}"
    );

    let control = tempfile::tempdir().unwrap();
    ok(Command::new("dpkg-deb")
        .arg("-e")
        .arg(&deb)
        .arg(control.path()));
    let conffiles = std::fs::read_to_string(control.path().join("conffiles")).unwrap();
    let want: Vec<String> = expected
        .iter()
        .filter(|(p, m)| p.starts_with("etc/") && !m.starts_with('d'))
        .map(|(p, _)| format!("/{p}"))
        .collect();
    let mut got: Vec<String> = conffiles.lines().map(String::from).collect();
    got.sort();
    assert_eq!(got, want, "conffiles");
    use std::os::unix::fs::PermissionsExt;
    for s in ["postinst", "prerm", "postrm"] {
        let p = control.path().join(s);
        let mode = std::fs::metadata(&p)
            .unwrap_or_else(|e| panic!("maintainer script {s}: {e}"))
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o755, "mode of {s}");
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.starts_with("#!/bin/sh\n"), "{s} is no sh script");
        ok(Command::new("sh").arg("-n").arg(&p));
    }
    let root = tempfile::tempdir().unwrap();
    ok(Command::new("dpkg-deb")
        .arg("-x")
        .arg(&deb)
        .arg(root.path()));
    ok(Command::new("sh").arg("-n").arg(
        root.path()
            .join("usr/lib/systemd/system-generators/shimmyd-sandbox-generator"),
    ));
    for b in ["shimmyd", "shimmy"] {
        let len = std::fs::metadata(root.path().join("usr/bin").join(b))
            .unwrap()
            .len();
        eprintln!("packaged {b}: {len} B");
    }
}

/// The package unpacked into a temporary directory.
fn unpacked(deb: &Path) -> tempfile::TempDir {
    let root = tempfile::tempdir().unwrap();
    ok(Command::new("dpkg-deb").arg("-x").arg(deb).arg(root.path()));
    root
}

/// `shimmyd --check` as the packaged binary in `root` runs it on the packaged configuration,
/// with no way to reach the source tree's profiles or the shared data's DBCs but the compiled-in
/// source path (which the packaged profile folder, first in the search order, shadows).
fn packaged_check(root: &Path, extra: &[&str], sandbox: Option<&str>) -> Output {
    let mut cmd = Command::new(root.join("usr/bin/shimmyd"));
    cmd.arg("--check")
        .arg("--config")
        .arg(root.join("etc/shimmyd/shimmyd.toml"))
        .args(extra)
        .current_dir(root)
        .env_remove("SHIMMY_PROFILES")
        .env_remove("SHIMMY_DBC_PATH")
        .env("SHIMMY_DATA_DIR", root.join("no-shared-data"));
    match sandbox {
        Some(v) => cmd.env("SHIMMYD_SANDBOX", v),
        None => cmd.env_remove("SHIMMYD_SANDBOX"),
    };
    run(&mut cmd)
}

#[test]
fn packaged_config_checks_with_every_packaged_profile() {
    let Some(deb) = package() else { return };
    let root = unpacked(&deb);
    let r = root.path();
    let vehicles = r.join("etc/shimmyd/vehicles");
    let cases = std::iter::once(("shimmy_reference".to_string(), None)).chain(
        profiles()
            .into_iter()
            .map(|(name, _, _)| (name.clone(), Some(name))),
    );
    for (name, flag) in cases {
        let extra: Vec<&str> = match &flag {
            Some(n) => vec!["--profile", n.as_str()],
            None => vec![],
        };
        let out = packaged_check(r, &extra, None);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "--check {extra:?} failed:\n{err}");
        let dir = vehicles.join(&name);
        assert!(
            err.contains(&format!("vehicle profile {}\n", dir.display())),
            "--check {extra:?} did not use the packaged profile {}:\n{err}",
            dir.display()
        );
        assert!(
            err.contains(&format!("DBC {}/", dir.display())),
            "--check {extra:?} did not use the packaged DBC:\n{err}"
        );
        assert!(err.contains("is valid"), "{err}");
    }
    ok(Command::new(r.join("usr/bin/shimmy")).arg("--version"));
}

/// The unit in `root` (the unpacked package) with its programs and configuration paths pointing
/// into `root`, in a fresh directory (with `dropin` as shimmyd.service.d/mqtt.conf), verified.
fn verify_rewritten(root: &Path, dropin: Option<&str>) {
    let unit =
        std::fs::read_to_string(root.join("usr/lib/systemd/system/shimmyd.service")).unwrap();
    let rewritten = unit
        .replace(
            "/usr/bin/shimmyd",
            &root.join("usr/bin/shimmyd").to_string_lossy(),
        )
        .replace(
            "/etc/shimmyd/",
            &format!("{}/", root.join("etc/shimmyd").display()),
        );
    assert_ne!(rewritten, unit, "the unit names no /usr/bin/shimmyd");
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("shimmyd.service"), rewritten).unwrap();
    if let Some(d) = dropin {
        std::fs::create_dir(dir.path().join("shimmyd.service.d")).unwrap();
        std::fs::write(dir.path().join("shimmyd.service.d/mqtt.conf"), d).unwrap();
    }
    verify(&dir.path().join("shimmyd.service"));
}

/// `systemd-analyze verify` prints nothing and succeeds.
fn verify(unit: &Path) {
    let out = run(Command::new("systemd-analyze")
        .args(["verify", "--man=no"])
        .arg(unit));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success() && text.trim().is_empty(),
        "systemd-analyze verify {}: {}\n{text}",
        unit.display(),
        out.status
    );
}

/// `systemd-analyze security --offline=true` of shimmyd.service in `root` (None: this machine):
/// the overall exposure and the full table.
fn exposure(root: Option<&Path>) -> (f64, String) {
    let mut cmd = Command::new("systemd-analyze");
    cmd.args(["security", "--offline=true", "--no-pager"]);
    if let Some(r) = root {
        cmd.arg(format!("--root={}", r.display()));
    }
    let text = ok(cmd.arg("shimmyd.service"));
    (
        parse_exposure(&text).unwrap_or_else(|| panic!("no overall exposure in:\n{text}")),
        text,
    )
}

/// The number of "Overall exposure level for shimmyd.service: 1.4 OK".
fn parse_exposure(text: &str) -> Option<f64> {
    let line = text
        .lines()
        .find(|l| l.contains("Overall exposure level for"))?;
    line.split(": ")
        .nth(1)?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Whether the security table marks `setting` as exposed (✗).
fn exposed(table: &str, setting: &str) -> bool {
    table
        .lines()
        .any(|l| l.starts_with('✗') && l.split_whitespace().nth(1) == Some(setting))
}

/// The packaged configuration with `[mqtt]` enabled to the broker `host`.
fn with_mqtt(root: &Path, host: &str) {
    let path = root.join("etc/shimmyd/shimmyd.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut changed = text.clone();
    for (from, to) in [
        ("\nenabled = false\n", "\nenabled = true\n".to_string()),
        ("\nhost = \"\"", format!("\nhost = \"{host}\"")),
        ("\nclient_id = \"\"", "\nclient_id = \"van-1\"".to_string()),
        ("\nfleet = \"\"", "\nfleet = \"vans\"".to_string()),
        // Plain TCP, so that the test needs no certificate files; the sandbox is the same.
        ("\ntransport = \"tls\"", "\ntransport = \"tcp\"".to_string()),
        ("\nport = 8883 ", "\nport = 1883 ".to_string()),
    ] {
        assert_eq!(changed.matches(from).count(), 1, "{from:?} in shimmyd.toml");
        changed = changed.replace(from, &to);
    }
    std::fs::write(&path, changed).unwrap();
}

/// Runs the packaged generator on `root`'s configuration; the drop-in it wrote, if any.
fn generate(root: &Path) -> Option<String> {
    let out = tempfile::tempdir().unwrap();
    ok(
        Command::new(root.join("usr/lib/systemd/system-generators/shimmyd-sandbox-generator"))
            .arg(out.path())
            .arg(out.path())
            .arg(out.path())
            .env("SHIMMYD_ROOT", root)
            .env_remove("SHIMMY_PROFILES")
            .env_remove("SHIMMY_DBC_PATH"),
    );
    std::fs::read_to_string(out.path().join("shimmyd.service.d/mqtt.conf")).ok()
}

#[test]
fn unit_verifies_and_exposure_stays_low_with_and_without_mqtt() {
    let Some(deb) = package() else { return };
    let root = unpacked(&deb);
    let r = root.path();

    // As packaged: MQTT off, no drop-in, the unit's sandbox alone.
    assert_eq!(
        generate(r),
        None,
        "a drop-in for a configuration without MQTT"
    );
    verify_rewritten(r, None);
    let (alone, table) = exposure(Some(r));
    eprintln!("exposure, unit alone: {alone}");
    assert!(alone <= 2.0, "exposure {alone} > 2.0:\n{table}");
    assert!(
        !exposed(&table, "RestrictAddressFamilies=~AF_(INET|INET6)"),
        "{table}"
    );
    assert!(!exposed(&table, "User=/DynamicUser="), "{table}");

    // [mqtt] enabled: the generator's drop-in opens exactly the broker's address.
    with_mqtt(r, "192.0.2.10");
    let dropin = generate(r).expect("no drop-in for a configuration with [mqtt] enabled");
    assert!(dropin.contains("\nIPAddressAllow=192.0.2.10\n"), "{dropin}");
    assert!(
        dropin.contains("\nRestrictAddressFamilies=AF_INET AF_INET6\n"),
        "{dropin}"
    );
    verify_rewritten(r, Some(&dropin));
    let d = r.join("etc/systemd/system/shimmyd.service.d");
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("mqtt.conf"), &dropin).unwrap();
    let (mqtt, table) = exposure(Some(r));
    eprintln!("exposure, with the MQTT drop-in (broker 192.0.2.10): {mqtt}");
    assert!(
        exposed(&table, "RestrictAddressFamilies=~AF_(INET|INET6)"),
        "the drop-in was not applied:\n{table}"
    );
    assert!(mqtt <= 2.0, "exposure with MQTT {mqtt} > 2.0:\n{table}");

    // The start check: the sandbox must have been made from this configuration.
    let stale = packaged_check(r, &[], Some("can"));
    let err = String::from_utf8_lossy(&stale.stderr);
    assert!(
        !stale.status.success() && err.contains("systemctl daemon-reload"),
        "--check accepted [mqtt] without its drop-in:\n{err}"
    );
    let env = dropin
        .lines()
        .find_map(|l| l.strip_prefix("Environment=SHIMMYD_SANDBOX="))
        .expect("the drop-in sets SHIMMYD_SANDBOX");
    let fresh = packaged_check(r, &[], Some(env));
    assert!(
        fresh.status.success(),
        "--check refused the matching drop-in:\n{}",
        String::from_utf8_lossy(&fresh.stderr)
    );
}

#[test]
fn exposure_lines_are_parsed() {
    let t = "✗ PrivateNetwork=      Service has access to the host's network     0.5\n\
             ✓ RestrictAddressFamilies=~AF_(INET|INET6)   Service cannot allocate Internet sockets\n\n\
             → Overall exposure level for shimmyd.service: 1.4 OK 🙂\n";
    assert_eq!(parse_exposure(t), Some(1.4));
    assert!(exposed(t, "PrivateNetwork="));
    assert!(!exposed(t, "RestrictAddressFamilies=~AF_(INET|INET6)"));
    assert_eq!(parse_exposure("no such line"), None);
}

fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions.
    unsafe { libc::geteuid() == 0 }
}

fn installed(pkg: &str) -> bool {
    run(Command::new("dpkg-query").args(["-W", "-f=${Status}", pkg]))
        .stdout
        .starts_with(b"install ok installed")
}

fn user_exists(name: &str) -> bool {
    run(Command::new("getent").args(["passwd", name]))
        .status
        .success()
}

/// Purges the package when the test ends, whatever happened.
struct Purge;
impl Drop for Purge {
    fn drop(&mut self) {
        let _ = Command::new("dpkg")
            .args(["--purge", "shimmy-monitor"])
            .output();
    }
}

#[test]
fn installs_removes_and_purges_for_real() {
    let asked = std::env::var("SHIMMY_DEB_INSTALL").is_ok_and(|v| v == "1");
    if !(in_ci() || asked) {
        eprintln!(
            "SKIPPED: real dpkg -i only as root under CI=true or with SHIMMY_DEB_INSTALL=1 (the \
             package creates a system user); the unpacked package is tested by the other tests"
        );
        return;
    }
    if !is_root() {
        skip("installing the package needs root");
        return;
    }
    let Some(deb) = package() else { return };
    let entries = expected_entries();
    if installed("shimmy-monitor") && in_ci() {
        // Left by an earlier run that was killed before its purge (CI's machine only).
        eprintln!("shimmy-monitor is installed: purging it first");
        ok(Command::new("dpkg").args(["--purge", "shimmy-monitor"]));
    }
    assert!(
        !installed("shimmy-monitor") && !user_exists("shimmyd"),
        "shimmy-monitor or the user shimmyd is already on this machine; the test installs and \
         purges them, so it refuses to run here"
    );
    for (p, _) in entries.iter().filter(|(_, m)| !m.starts_with('d')) {
        assert!(
            !Path::new("/").join(p).exists(),
            "/{p} exists before installing"
        );
    }
    let wants = Path::new("/etc/systemd/system/multi-user.target.wants/shimmyd.service");
    let _purge = Purge;
    ok(Command::new("dpkg").arg("-i").arg(&deb));

    // The user: a system account without login, home /var/lib/shimmyd, owning that directory.
    let pw = ok(Command::new("getent").args(["passwd", "shimmyd"]));
    let f: Vec<&str> = pw.trim().split(':').collect();
    assert_eq!(f.len(), 7, "{pw}");
    let uid: u32 = f[2].parse().unwrap();
    assert!(uid < 1000, "not a system uid: {pw}");
    assert_eq!(f[5], "/var/lib/shimmyd", "{pw}");
    assert!(f[6].ends_with("nologin"), "{pw}");
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let st = std::fs::metadata("/var/lib/shimmyd").expect("/var/lib/shimmyd");
    assert!(st.is_dir());
    assert_eq!(st.uid(), uid, "owner of /var/lib/shimmyd");
    assert_eq!(st.permissions().mode() & 0o777, 0o750);
    if tool("systemctl").is_some() {
        assert!(
            wants.is_symlink(),
            "shimmyd.service not enabled: {} missing",
            wants.display()
        );
    }
    for p in entries.keys() {
        assert!(Path::new("/").join(p).exists(), "/{p} not installed");
    }

    // The installed configuration, checked by the installed daemon, from outside the tree.
    let check = ok(Command::new("/usr/bin/shimmyd")
        .args(["--check", "--config", "/etc/shimmyd/shimmyd.toml"])
        .current_dir("/")
        .env_remove("SHIMMY_PROFILES")
        .env_remove("SHIMMY_DBC_PATH")
        .env_remove("SHIMMYD_SANDBOX")
        .env("SHIMMY_DATA_DIR", "/nonexistent"));
    assert!(
        check.contains("vehicle profile /etc/shimmyd/vehicles/shimmy_reference\n"),
        "{check}"
    );
    verify(Path::new("/usr/lib/systemd/system/shimmyd.service"));
    let (x, table) = exposure(None);
    eprintln!("exposure, installed unit: {x}");
    assert!(x <= 2.0, "installed unit's exposure {x} > 2.0:\n{table}");
    let gen = tempfile::tempdir().unwrap();
    ok(
        Command::new("/usr/lib/systemd/system-generators/shimmyd-sandbox-generator")
            .arg(gen.path())
            .env_remove("SHIMMYD_ROOT"),
    );
    assert!(
        !gen.path().join("shimmyd.service.d").exists(),
        "the generator wrote a drop-in for the packaged configuration (MQTT off)"
    );

    // Remove: programs gone, configuration and user data kept.
    std::fs::write("/var/lib/shimmyd/journal-marker", "x").unwrap();
    ok(Command::new("dpkg").args(["-r", "shimmy-monitor"]));
    assert!(!Path::new("/usr/bin/shimmyd").exists());
    assert!(!Path::new("/usr/lib/systemd/system/shimmyd.service").exists());
    assert!(
        Path::new("/etc/shimmyd/shimmyd.toml").exists(),
        "remove deleted a conffile"
    );
    assert!(
        Path::new("/var/lib/shimmyd/journal-marker").exists(),
        "remove deleted user data"
    );

    // Purge: nothing left.
    ok(Command::new("dpkg").args(["--purge", "shimmy-monitor"]));
    let dpkg_knows = run(Command::new("dpkg-query").args(["-W", "shimmy-monitor"]));
    assert!(
        !dpkg_knows.status.success(),
        "dpkg still knows shimmy-monitor after purge"
    );
    let mut left: Vec<String> = entries
        .keys()
        .map(|p| format!("/{p}"))
        .filter(|p| {
            let p = Path::new(p);
            // Shared system directories stay (usr, usr/bin, etc, ...): only the package's own.
            p.exists()
                && (p.is_file() || p.starts_with("/etc/shimmyd") || p.ends_with("shimmy-monitor"))
        })
        .collect();
    for p in [
        "/var/lib/shimmyd",
        "/etc/shimmyd",
        "/run/systemd/generator/shimmyd.service.d",
    ] {
        if Path::new(p).exists() {
            left.push(p.to_string());
        }
    }
    if wants.is_symlink() {
        left.push(wants.display().to_string());
    }
    assert!(left.is_empty(), "left behind after purge: {left:?}");
    assert!(
        !user_exists("shimmyd"),
        "the user shimmyd survived the purge"
    );
    assert!(
        !run(Command::new("getent").args(["group", "shimmyd"]))
            .status
            .success(),
        "the group shimmyd survived the purge"
    );
}
