//! shimmyd's MQTT output over TLS against a real `mosquitto` broker with a test PKI the test
//! makes with the `openssl` command: a fleet CA that signs the broker's certificate (for
//! 127.0.0.1) and the vehicle's client certificate, and a foreign CA.
//!
//! The broker has two listeners: TLS with `require_certificate` for the daemon, and a plain one
//! on loopback for the test's subscriber. The daemon replays the demo log each run.
//!
//! * The right CA and client certificate: every journaled event and alert arrives once, in order.
//! * Refused, each with a log line saying why, and nothing delivered: a CA that did not sign the
//!   broker's certificate; an expired client certificate; a client certificate from a foreign
//!   CA; TLS configured towards a plain-TCP listener. After each, a run with the right settings
//!   delivers everything the refused run left in the outbox, then its own messages: nothing
//!   lost, nothing twice.
//!
//! Without mosquitto or openssl the test prints SKIPPED and passes, except under CI=true, where
//! it fails.

use std::path::Path;
use std::process::Command;

mod mqtt_common;
use mqtt_common::*;

fn run_openssl(bin: &Path, dir: &Path, args: &[&str]) {
    let out = Command::new(bin)
        .args(args)
        .current_dir(dir)
        .output()
        .expect("cannot run openssl");
    assert!(
        out.status.success(),
        "openssl {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A P-256 key `<name>.key` and a self-signed CA certificate `<name>.pem` in `dir`.
fn make_ca(bin: &Path, dir: &Path, name: &str) {
    let (key, pem, subj) = (
        format!("{name}.key"),
        format!("{name}.pem"),
        format!("/CN={name}"),
    );
    run_openssl(
        bin,
        dir,
        &[
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:P-256",
            "-nodes",
            "-keyout",
            &key,
            "-out",
            &pem,
            "-days",
            "30",
            "-subj",
            &subj,
        ],
    );
}

/// A key `<name>.key` and a certificate `<name>.pem` for `cn` signed by CA `ca`, valid for
/// `days` (-1: expired), with extensions `ext` (an openssl extfile's lines).
fn make_cert(bin: &Path, dir: &Path, name: &str, cn: &str, ca: &str, days: i32, ext: &str) {
    let (key, pem, csr, extf) = (
        format!("{name}.key"),
        format!("{name}.pem"),
        format!("{name}.csr"),
        format!("{name}.ext"),
    );
    std::fs::write(dir.join(&extf), ext).unwrap();
    let subj = format!("/CN={cn}");
    run_openssl(
        bin,
        dir,
        &[
            "req",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:P-256",
            "-nodes",
            "-keyout",
            &key,
            "-out",
            &csr,
            "-subj",
            &subj,
        ],
    );
    let (ca_pem, ca_key, days) = (format!("{ca}.pem"), format!("{ca}.key"), days.to_string());
    run_openssl(
        bin,
        dir,
        &[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            &ca_pem,
            "-CAkey",
            &ca_key,
            "-CAcreateserial",
            "-out",
            &pem,
            "-days",
            &days,
            "-extfile",
            &extf,
        ],
    );
}

/// The test PKI in `dir`: fleet-ca (broker `server`, vehicle `van`, `van-expired`), foreign-ca
/// (vehicle `van-foreign`).
fn make_pki(bin: &Path, dir: &Path) {
    make_ca(bin, dir, "fleet-ca");
    make_ca(bin, dir, "foreign-ca");
    let server = "subjectAltName = IP:127.0.0.1, DNS:localhost\nextendedKeyUsage = serverAuth\n";
    let client = "extendedKeyUsage = clientAuth\n";
    make_cert(bin, dir, "server", "broker", "fleet-ca", 30, server);
    make_cert(bin, dir, "van", CLIENT_ID, "fleet-ca", 30, client);
    make_cert(bin, dir, "van-expired", CLIENT_ID, "fleet-ca", -1, client);
    make_cert(bin, dir, "van-foreign", CLIENT_ID, "foreign-ca", 30, client);
}

/// `[mqtt]` TLS lines: CA `ca`, client certificate and key `client`.
fn tls(pki: &Path, ca: &str, client: &str) -> String {
    let p = |f: String| format!("{:?}", pki.join(f).display().to_string());
    format!(
        "ca_file = {}\ncert_file = {}\nkey_file = {}",
        p(format!("{ca}.pem")),
        p(format!("{client}.pem")),
        p(format!("{client}.key"))
    )
}

/// Runs the daemon on `cfg`; its stderr, after checking it exited successfully.
fn run(cfg: &Path) -> String {
    let out = daemon(cfg).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err}");
    err
}

#[test]
fn mutual_tls_delivers_and_every_refusal_is_explained_and_loses_nothing() {
    let _one_at_a_time = serial();
    let Some(mosq) = mosquitto() else { return };
    let Some(ssl) = openssl() else { return };
    let dir = tempfile::tempdir().unwrap();
    let pki = dir.path().join("pki");
    let bdir = dir.path().join("broker");
    let ddir = dir.path().join("daemon");
    for d in [&pki, &bdir, &ddir] {
        std::fs::create_dir(d).unwrap();
    }
    make_pki(&ssl, &pki);
    let (tls_port, plain_port) = (free_port(), free_port());
    let f = |n: &str| pki.join(n).display().to_string();
    let listeners = format!(
        "listener {plain_port} 127.0.0.1\n\
         listener {tls_port} 127.0.0.1\ncafile {}\ncertfile {}\nkeyfile {}\nrequire_certificate true\n",
        f("fleet-ca.pem"),
        f("server.pem"),
        f("server.key")
    );
    let _broker = Broker::start_conf(&mosq, &bdir, &listeners, &[plain_port, tls_port]);
    let sub = Sub::connect(plain_port, "test-sub-tls", false);

    // (what is wrong, [mqtt] lines and port, what the log must say)
    let good = tls(&pki, "fleet-ca", "van");
    let refusals: Vec<(&str, String, u16, &[&str])> = vec![
        (
            "a CA that did not sign the broker's certificate",
            tls(&pki, "foreign-ca", "van"),
            tls_port,
            &["not trusted", "mqtt.ca_file"],
        ),
        (
            "an expired client certificate",
            tls(&pki, "fleet-ca", "van-expired"),
            tls_port,
            &["refused this vehicle's client certificate", "expired"],
        ),
        (
            "a client certificate of a foreign CA",
            tls(&pki, "fleet-ca", "van-foreign"),
            tls_port,
            &[
                "refused this vehicle's client certificate",
                "van-foreign.pem",
            ],
        ),
        (
            "TLS towards a plain-TCP listener",
            good.clone(),
            plain_port,
            &["plain-TCP listener"],
        ),
    ];

    // The right settings first: everything arrives.
    let err = run(&config(&ddir, tls_port, 10.0, &good));
    assert!(err.contains("over TLS"), "{err}");
    assert!(err.contains("mqtt: connected to"), "{err}");
    assert!(!err.contains("still queued"), "{err}");
    let mut delivered = 0;
    let want = journaled(&ddir);
    assert!(
        want.iter().any(|(k, _, _)| *k == "alert"),
        "no alert journaled"
    );
    let got = sub.collect(want.len());
    check_delivery(&got, &want);
    delivered += got.len();

    for (what, lines, port, needles) in &refusals {
        let err = run(&config(&ddir, *port, 0.6, lines));
        assert!(
            !err.contains("mqtt: connected to"),
            "{what}: connected:\n{err}"
        );
        assert!(
            err.contains("still queued"),
            "{what}: nothing queued:\n{err}"
        );
        for n in *needles {
            assert!(
                err.contains(n),
                "{what}: the log does not say `{n}`:\n{err}"
            );
        }
        for l in err.lines().filter(|l| l.contains("unreachable")) {
            eprintln!("{what}: {l}");
        }
        let queued = journaled(&ddir).len() - delivered;
        assert!(
            err.contains(&format!("{queued} message(s) still queued")),
            "{what}: {queued} messages should be queued:\n{err}"
        );
        assert!(
            sub.rx.try_recv().is_err(),
            "{what}: a message reached the broker"
        );
        // Fixed: what the refused run queued arrives, then this run's own messages.
        let err = run(&config(&ddir, tls_port, 10.0, &good));
        assert!(
            err.contains(&format!("{queued} message(s) queued from before")),
            "{what}: {err}"
        );
        assert!(!err.contains("still queued"), "{what}: {err}");
        let want = journaled(&ddir);
        let got = sub.collect(want.len() - delivered);
        check_delivery(&got, &want[delivered..]);
        delivered += got.len();
        eprintln!("refused and then delivered: {what}");
    }
    sub.disconnect();
}

/// The files' problems stop the daemon at start, naming the key and the file.
#[test]
fn unusable_tls_files_stop_the_daemon_at_start() {
    let Some(ssl) = openssl() else { return };
    let dir = tempfile::tempdir().unwrap();
    let pki = dir.path().join("pki");
    std::fs::create_dir(&pki).unwrap();
    make_pki(&ssl, &pki);
    std::fs::write(pki.join("empty.pem"), "not a certificate\n").unwrap();
    let key_of_other = {
        // The right certificate with the key of another one.
        std::fs::copy(pki.join("van.pem"), pki.join("mixed.pem")).unwrap();
        std::fs::copy(pki.join("van-foreign.key"), pki.join("mixed.key")).unwrap();
        "mixed"
    };
    let port = free_port();
    let cases: Vec<(String, &[&str])> = vec![
        (tls(&pki, "empty", "van"), &["mqtt.ca_file", "empty.pem"]),
        (
            tls(&pki, "fleet-ca", key_of_other),
            &["mqtt.cert_file", "mixed.pem"],
        ),
    ];
    for (lines, needles) in cases {
        let ddir = tempfile::tempdir().unwrap();
        let out = daemon(&config(ddir.path(), port, 0.1, &lines))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{lines}: started:\n{err}");
        for n in needles {
            assert!(
                err.contains(n),
                "{lines}: error does not mention `{n}`:\n{err}"
            );
        }
    }
}
