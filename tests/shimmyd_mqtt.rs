//! shimmyd's MQTT output against a real `mosquitto` broker (Debian package `mosquitto`), which
//! each test starts itself on a free loopback port with a temporary configuration.
//!
//! * Broker up: every event and every alert transition the daemon journals while replaying the
//!   demo log (firmware-sim, 0.2 mm joints; with `shimmy_confirm = 1` its 55 km/h event raises
//!   the shimmy alert) arrives on the broker, once, in order, with the journal's content.
//! * Broker down at start: the messages wait in the daemon's on-disk outbox, survive a daemon
//!   restart, and are all delivered exactly once and in order when the broker comes up while
//!   the daemon runs.
//!
//! Without mosquitto the tests print SKIPPED and pass, except under CI=true, where they fail.

use std::io::{BufRead, BufReader};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use rumqttc::{Client, Event, MqttOptions, Packet, QoS};
use serde_json::Value;
use shimmy::journal::Reader;

const CLIENT_ID: &str = "test-van";

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The mosquitto binary, or None (after saying why) when the test should skip.
fn mosquitto() -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).collect())
        .unwrap_or_default();
    dirs.extend(["/usr/sbin", "/usr/local/sbin", "/sbin"].map(PathBuf::from));
    if let Some(p) = dirs
        .iter()
        .map(|d| d.join("mosquitto"))
        .find(|p| p.is_file())
    {
        return Some(p);
    }
    let why = "mosquitto not found on PATH or in /usr/sbin (Debian: apt-get install mosquitto)";
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{why}; required under CI=true");
    }
    eprintln!("SKIPPED: {why}");
    None
}

/// The tests run one at a time: run in parallel on a loaded machine, a subscriber's first
/// connection to a just-started broker was seen to be dropped (1 run in 5), while serially
/// 6 of 6 runs passed.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A broker process on 127.0.0.1:port, persisting sessions in `dir` (so a subscriber's
/// session survives a broker restart); SIGTERM on drop.
struct Broker {
    child: Child,
}

impl Broker {
    fn start(bin: &Path, dir: &Path, port: u16) -> Broker {
        let conf = dir.join("mosquitto.conf");
        let mut text = format!(
            "listener {port} 127.0.0.1\nallow_anonymous true\npersistence true\npersistence_location {}/\nlog_dest file {}\n",
            dir.display(),
            dir.join("mosquitto.log").display()
        );
        // As root, mosquitto would switch to the `mosquitto` user, who cannot write the
        // temporary directory.
        if unsafe { libc::geteuid() } == 0 {
            text += "user root\n";
        }
        std::fs::write(&conf, text).unwrap();
        let child = Command::new(bin)
            .arg("-c")
            .arg(&conf)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("cannot start mosquitto");
        let deadline = Instant::now() + Duration::from_secs(10);
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "mosquitto did not listen on port {port}: {}",
                std::fs::read_to_string(dir.join("mosquitto.log")).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        Broker { child }
    }

    /// SIGTERM (mosquitto saves its persistence file) and wait.
    fn stop(mut self) {
        self.term();
    }

    fn term(&mut self) {
        unsafe {
            libc::kill(self.child.id() as i32, libc::SIGTERM);
        }
        let _ = self.child.wait();
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.term();
        }
    }
}

/// A subscriber to `fleet/#` (QoS 1) collecting (topic, payload).
struct Sub {
    client: Client,
    rx: mpsc::Receiver<(String, Value)>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Sub {
    /// Connects and waits for the subscription to be acknowledged. `persistent`: a session the
    /// broker keeps (and queues QoS 1 messages for) while the subscriber is away.
    fn connect(port: u16, id: &str, persistent: bool) -> Sub {
        let mut o = MqttOptions::new(id, "127.0.0.1", port);
        o.set_clean_session(!persistent)
            .set_keep_alive(Duration::from_secs(5));
        let (client, mut conn) = Client::new(o, 64);
        client.subscribe("fleet/#", QoS::AtLeastOnce).unwrap();
        let (tx, rx) = mpsc::channel();
        let (ready_tx, ready_rx) = mpsc::channel();
        let thread = std::thread::spawn(move || {
            for ev in conn.iter() {
                match ev {
                    Ok(Event::Incoming(Packet::SubAck(_))) => {
                        let _ = ready_tx.send(());
                    }
                    Ok(Event::Incoming(Packet::Publish(p))) => {
                        let v: Value = serde_json::from_slice(&p.payload).expect("JSON payload");
                        if tx.send((p.topic.clone(), v)).is_err() {
                            return;
                        }
                    }
                    Ok(_) => {}
                    Err(_) => return,
                }
            }
        });
        ready_rx
            .recv_timeout(Duration::from_secs(10))
            .expect("subscription not acknowledged");
        Sub {
            client,
            rx,
            thread: Some(thread),
        }
    }

    /// Collects until `n` messages arrived (or 20 s passed), then 300 ms more to catch extras.
    fn collect(&self, n: usize) -> Vec<(String, Value)> {
        let mut got = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(20);
        while got.len() < n && Instant::now() < deadline {
            if let Ok(m) = self.rx.recv_timeout(Duration::from_millis(100)) {
                got.push(m);
            }
        }
        while let Ok(m) = self.rx.recv_timeout(Duration::from_millis(300)) {
            got.push(m);
        }
        got
    }

    fn disconnect(mut self) {
        let _ = self.client.disconnect();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The demo daemon configuration with absolute paths, journal and state in `dir`, and MQTT on.
fn config(dir: &Path, port: u16, drain_s: f64) -> PathBuf {
    let demo = workspace().join("config/demo");
    let text = std::fs::read_to_string(demo.join("shimmyd.toml")).unwrap();
    let abs = |rel: &str| demo.join(rel).canonicalize().unwrap().display().to_string();
    let text = text
        .replace("\"../../dbc/", &format!("\"{}/", abs("../../dbc")))
        .replace("\"../vehicles/", &format!("\"{}/", abs("../vehicles")))
        .replace("\"../vehicle/", &format!("\"{}/", abs("../vehicle")))
        .replace(
            "\"../../target/demo/journal\"",
            &format!("{:?}", dir.join("journal").display().to_string()),
        )
        .replace(
            "\"../../target/demo/state\"",
            &format!("{:?}", dir.join("state").display().to_string()),
        );
    // One event above 0.2 deg at 50-60 km/h raises the shimmy alert (the demo has one such
    // event; the default asks for two). The alert settings are the monitor file's: a copy of
    // the one the demo names, beside this config.
    let monitor_from = "monitor = \"../observer.toml\"";
    assert!(
        text.contains(monitor_from),
        "demo config names no monitor file"
    );
    let text = text.replacen(monitor_from, "monitor = \"observer.toml\"", 1);
    let monitor = std::fs::read_to_string(demo.join("../observer.toml")).unwrap();
    assert!(monitor.contains("shimmy_confirm = 2"));
    std::fs::write(
        dir.join("observer.toml"),
        monitor.replacen("shimmy_confirm = 2", "shimmy_confirm = 1", 1),
    )
    .unwrap();
    let mqtt_from = "enabled = false\nhost = \"\"";
    assert!(
        text.contains(mqtt_from),
        "demo config lacks the [mqtt] keys"
    );
    let text = text
        .replacen(mqtt_from, "enabled = true\nhost = \"127.0.0.1\"", 1)
        .replacen("port = 1883", &format!("port = {port}"), 1)
        .replacen(
            "client_id = \"\"",
            &format!("client_id = \"{CLIENT_ID}\""),
            1,
        )
        .replacen("topic_prefix = \"shimmy\"", "topic_prefix = \"fleet\"", 1)
        .replacen("reconnect_s = 2.0", "reconnect_s = 0.2", 1)
        .replacen(
            "drain_timeout_s = 2.0",
            &format!("drain_timeout_s = {drain_s}"),
            1,
        );
    let p = dir.join("shimmyd.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn demo_log() -> PathBuf {
    workspace().join("tests/fixtures/demo/worn_0p2mm.log")
}

fn daemon(cfg: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_shimmyd"));
    c.arg("--config")
        .arg(cfg)
        .arg("--replay")
        .arg(demo_log())
        .arg("--fast");
    c
}

/// The messages the journal says were published: (topic suffix, record), in journal order.
fn journaled(dir: &Path) -> Vec<(&'static str, Value)> {
    let mut out = Vec::new();
    for e in Reader::open(&dir.join("journal")).unwrap() {
        let rec = e.unwrap().rec;
        match rec["type"].as_str() {
            Some("event") => out.push(("event", rec["event"].clone())),
            Some("alert") => out.push(("alert", rec.clone())),
            _ => {}
        }
    }
    out
}

/// Every journaled event and alert arrived once, in order, with consecutive ids.
fn check_delivery(got: &[(String, Value)], want: &[(&str, Value)]) {
    assert_eq!(
        got.len(),
        want.len(),
        "{} message(s) received, {} journaled",
        got.len(),
        want.len()
    );
    let mut prev = None;
    for ((topic, msg), (kind, rec)) in got.iter().zip(want) {
        assert_eq!(topic, &format!("fleet/{CLIENT_ID}/{kind}"));
        assert_eq!(msg["type"], *kind);
        let seq = msg["seq"].as_u64().expect("seq");
        assert_eq!(msg["id"], format!("{CLIENT_ID}:{seq}"));
        if let Some(p) = prev {
            assert_eq!(
                seq,
                p + 1,
                "out of order, lost or duplicated: {seq} after {p}"
            );
        }
        prev = Some(seq);
        assert_eq!(msg["queue_dropped"], 0);
        match *kind {
            "event" => assert_eq!(msg["event"], *rec),
            _ => {
                assert_eq!(msg["transition"], rec["transition"]);
                assert_eq!(msg["alert"], rec["alert"]);
            }
        }
    }
}

/// Replays the demo against a running broker with `qos`; checks delivery against the journal.
fn replay_against_a_running_broker(qos: u8) {
    let Some(bin) = mosquitto() else { return };
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = Broker::start(&bin, dir.path(), port);
    let sub = Sub::connect(port, &format!("test-sub-qos{qos}"), false);
    let cfg = config(dir.path(), port, 10.0);
    let text = std::fs::read_to_string(&cfg).unwrap();
    assert!(text.contains("qos = 1 "));
    std::fs::write(&cfg, text.replacen("qos = 1 ", &format!("qos = {qos} "), 1)).unwrap();
    let out = daemon(&cfg).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("mqtt: connected to"), "{err}");
    assert!(err.contains(&format!("(QoS {qos})")), "{err}");

    let want = journaled(dir.path());
    let alerts = want.iter().filter(|(k, _)| *k == "alert").count();
    assert!(alerts >= 1, "the demo log should raise alerts:\n{err}");
    assert!(
        want.iter()
            .any(|(k, r)| *k == "alert" && r["alert"]["kind"] == "shimmy_55kmh"),
        "the 0.2 mm demo should raise the shimmy alert:\n{err}"
    );
    let got = sub.collect(want.len());
    check_delivery(&got, &want);
    // Nothing left behind in the outbox.
    assert!(!err.contains("still queued"), "{err}");
    sub.disconnect();
}

#[test]
fn every_alert_and_event_reaches_a_running_broker() {
    let _one_at_a_time = serial();
    replay_against_a_running_broker(1);
}

#[test]
fn qos_0_and_2_deliver_too() {
    let _one_at_a_time = serial();
    replay_against_a_running_broker(0);
    replay_against_a_running_broker(2);
}

#[test]
fn messages_wait_for_a_broker_that_is_down_and_arrive_once_in_order() {
    let _one_at_a_time = serial();
    let Some(bin) = mosquitto() else { return };
    let dir = tempfile::tempdir().unwrap();
    let bdir = dir.path().join("broker");
    std::fs::create_dir(&bdir).unwrap();
    let port = free_port();

    // A persistent subscriber session, registered while the broker is up; the broker keeps it
    // (and its subscription) across its restart.
    let broker = Broker::start(&bin, &bdir, port);
    Sub::connect(port, "test-sub-2", true).disconnect();
    broker.stop();

    // Run 1: broker down all the time; the daemon gives up draining after 0.3 s and leaves its
    // messages in the outbox.
    let cfg = config(dir.path(), port, 0.3);
    let out = daemon(&cfg).output().unwrap();
    let err1 = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err1}");
    assert!(err1.contains("unreachable"), "{err1}");
    assert!(err1.contains("still queued"), "{err1}");
    let after_run1 = journaled(dir.path()).len();
    assert!(after_run1 > 0);
    let events_per_run = journaled(dir.path())
        .iter()
        .filter(|(k, _)| *k == "event")
        .count();

    // Run 2 (same state and outbox): starts with the broker still down, replays again, and the
    // broker comes up while it waits to drain.
    let cfg = config(dir.path(), port, 30.0);
    let mut child = daemon(&cfg)
        .stderr(Stdio::piped())
        .spawn()
        .expect("cannot start shimmyd");
    let (tx, rx) = mpsc::channel::<String>();
    let stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut err2 = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    // Wait until the replay is over (the last event is journaled when the input ends) and the
    // daemon has found the broker unreachable.
    loop {
        let line = rx
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .unwrap_or_else(|_| panic!("daemon did not finish its replay:\n{}", err2.join("\n")));
        err2.push(line);
        let events = err2
            .iter()
            .filter(|l| l.contains("braking event at"))
            .count();
        if events == events_per_run && err2.iter().any(|l| l.contains("unreachable")) {
            break;
        }
    }
    assert!(
        err2.iter()
            .any(|l| l.contains(&format!("{after_run1} message(s) queued from before"))),
        "run 2 should find run 1's messages in the outbox:\n{}",
        err2.join("\n")
    );
    let _broker = Broker::start(&bin, &bdir, port);
    let status = child.wait().unwrap();
    reader.join().unwrap();
    err2.extend(rx.try_iter());
    let err2 = err2.join("\n");
    assert!(status.success(), "{err2}");
    assert!(err2.contains("mqtt: connected to"), "{err2}");
    assert!(!err2.contains("still queued"), "{err2}");

    let want = journaled(dir.path());
    assert!(want.len() > after_run1);
    assert!(
        want.iter().any(|(k, _)| *k == "alert"),
        "no alert journaled"
    );
    let sub = Sub::connect(port, "test-sub-2", true);
    let got = sub.collect(want.len());
    check_delivery(&got, &want);
    assert_eq!(
        got[0].1["seq"], 1,
        "the first message of run 1 is delivered first"
    );
    sub.disconnect();
}
