//! The optional MQTT 5 output to a fleet backend: braking events, clearance estimates, alert
//! transitions and the vehicle's online status, published by an outgoing `rumqttc` client
//! from the daemon's journal through [`super::outbox::Outbox`], so nothing is lost while the
//! broker is unreachable and nothing is stored twice.
//!
//! What it is: [`Publisher`], which owns one connection thread. The daemon tells it how far
//! its journal is durable ([`Publisher::journal_durable`]); the thread reads the new records
//! that are messages, sends the front one, waits for the broker's acknowledgement (QoS 1:
//! PUBACK, QoS 2: PUBCOMP, QoS 0: written to the socket), moves the cursor past it and sends the
//! next. One message in flight at a time keeps the order strict across reconnects; the rate it
//! allows (one broker round trip per message) is far above the daemon's (a few messages per
//! braking event). When the connection fails, the message in flight stays at the front and is
//! sent again after the reconnect, which is tried every `mqtt.reconnect_s`.
//!
//! Topics: `<topic_prefix>/v1/<fleet>/<vehicle>/{event,estimate,alert,status}` (`topic_prefix`
//! default `shimmy`, `vehicle` = `mqtt.client_id`). Payload: one JSON object with `id`
//! (`"<vehicle>:<journal seq>"`, unique and increasing, the de-duplication key for
//! at-least-once delivery, see [`super::outbox`]), `seq`, `type`, `queue_dropped` (the running
//! drop count) and the journal record's fields. MQTT 5 properties: the user property
//! `schema` = [`SCHEMA_VERSION`] on every message, content type `application/json`, and a
//! message expiry interval (`mqtt.estimate_expiry_s`) on estimates, which are worthless once a
//! newer one exists. `status` is retained: `{"status":"online"}` published on every connect,
//! `{"status":"offline","reason":"lost"}` as the last will (the broker publishes it when the
//! connection is lost without a goodbye) and `{"status":"offline","reason":"stopped"}` on a
//! clean stop.
//!
//! Transport: TLS ([`super::tls`]: the broker verified against `mqtt.ca_file`, this vehicle
//! authenticated by its client certificate) unless the configuration says `transport = "tcp"`.
//! A failed TLS connection is logged with what it means (untrusted broker, refused client
//! certificate, plain listener) and retried like any other outage; the outbox keeps everything
//! meanwhile.
//!
//! What it is not: a listener or a server. It makes one outgoing connection, only when
//! `[mqtt] enabled = true`.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Context;
use rumqttc::v5::mqttbytes::v5::{LastWill, Packet, PubAckReason, PublishProperties};
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{Client, Connection, ConnectionError, Event, MqttOptions, RecvTimeoutError};
use rumqttc::Outgoing;

use super::config::{MqttSection, Transport};
use super::outbox::{Limits, Opened, Outbox};

/// The payload schema's version, sent as the user property `schema` with every message.
pub const SCHEMA_VERSION: &str = "1";

fn log(msg: impl std::fmt::Display) {
    eprintln!("shimmyd: mqtt: {msg}");
}

/// Broker connect timeout (s): also bounds how long a stop can wait for a connect attempt.
const CONNECT_TIMEOUT_S: u64 = 3;
/// While connected, the thread checks the stop flag and the journal this often.
const POLL: Duration = Duration::from_millis(100);
/// "Broker unreachable" is logged at the first failure and then at most this often.
const UNREACHABLE_LOG_EVERY: Duration = Duration::from_secs(60);

struct Inner {
    outbox: Outbox,
    connected: bool,
    /// The message sent and not yet acknowledged: (seq, packet id once known).
    inflight: Option<(u64, Option<u16>)>,
    /// Publishes handed to the client, in order, whose packet id is not known yet: the
    /// message's seq, or None for a status message (not tracked).
    handed: VecDeque<Option<u64>>,
    delivered: u64,
    /// The journal's durable seq the outbox has read up to.
    refilled: u64,
}

struct Shared {
    inner: Mutex<Inner>,
    stop: AtomicBool,
    /// The journal's durable sequence number (+1; 0 = nothing durable yet).
    durable: AtomicU64,
    client: Client,
    qos: QoS,
    /// `<topic_prefix>/v1/<fleet>/<vehicle>/`.
    topic_base: String,
    vehicle: String,
    estimate_expiry_s: u32,
}

fn props(expiry_s: Option<u32>) -> PublishProperties {
    PublishProperties {
        content_type: Some("application/json".into()),
        message_expiry_interval: expiry_s,
        user_properties: vec![("schema".into(), SCHEMA_VERSION.into())],
        ..Default::default()
    }
}

/// The status message; `reason` tells a clean stop (`stopped`) from the last will (`lost`).
fn status_payload(vehicle: &str, status: &str, reason: Option<&str>) -> String {
    serde_json::json!({ "vehicle": vehicle, "status": status, "reason": reason }).to_string()
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Inner> {
        // A panic in the other thread while holding the lock leaves the cursor consistent on
        // disk (it is written atomically), so the poisoned guard is still usable.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Reads what the journal made durable since the last call into the outbox.
    fn refill(&self, inner: &mut Inner) {
        let d = self.durable.load(Ordering::Acquire);
        if d == 0 || d <= inner.refilled {
            return;
        }
        match inner.outbox.refill(d - 1) {
            Ok(dropped) => {
                inner.refilled = d;
                for s in &dropped {
                    log(format_args!(
                        "queue full (mqtt.queue_max_messages / queue_max_mib): dropped the oldest queued message {}:{s} ({} dropped in total; it stays in the journal)",
                        self.vehicle,
                        inner.outbox.dropped()
                    ));
                }
            }
            Err(e) => log(format_args!("cannot read the journal: {e:#}")),
        }
    }

    /// Sends the front message when connected and nothing is in flight.
    fn pump(&self, inner: &mut Inner) {
        self.refill(inner);
        if !inner.connected || inner.inflight.is_some() {
            return;
        }
        let Some(m) = inner.outbox.front() else {
            return;
        };
        let mut obj = serde_json::Map::new();
        obj.insert("id".into(), format!("{}:{}", self.vehicle, m.seq).into());
        obj.insert("seq".into(), m.seq.into());
        obj.insert("type".into(), m.kind.into());
        obj.insert("queue_dropped".into(), inner.outbox.dropped().into());
        obj.extend(m.body.clone());
        let payload = serde_json::Value::Object(obj).to_string();
        let expiry = (m.kind == "estimate").then_some(self.estimate_expiry_s);
        let topic = format!("{}{}", self.topic_base, m.kind);
        let seq = m.seq;
        match self.client.try_publish_with_properties(
            topic,
            self.qos,
            false,
            payload,
            props(expiry),
        ) {
            Ok(()) => {
                inner.inflight = Some((seq, None));
                inner.handed.push_back(Some(seq));
            }
            Err(e) => log(format_args!("cannot hand message {seq} to the client: {e}")),
        }
    }

    /// Publishes the retained status (`online` / `offline`), QoS 1, untracked.
    fn status(&self, inner: &mut Inner, status: &str, reason: Option<&str>) {
        let topic = format!("{}status", self.topic_base);
        if self
            .client
            .try_publish_with_properties(
                topic,
                QoS::AtLeastOnce,
                true,
                status_payload(&self.vehicle, status, reason),
                props(None),
            )
            .is_ok()
        {
            inner.handed.push_back(None);
        }
    }

    fn acked(&self, inner: &mut Inner, pkid: u16) {
        if let Some((seq, Some(p))) = inner.inflight {
            if p == pkid {
                self.done(inner, seq);
            }
        }
    }

    fn done(&self, inner: &mut Inner, seq: u64) {
        inner.inflight = None;
        match inner.outbox.delivered(seq) {
            Ok(true) => inner.delivered += 1,
            Ok(false) => {}
            Err(e) => log(format_args!(
                "message {seq} delivered but the cursor could not be saved (it will be sent again after a restart): {e:#}"
            )),
        }
        self.pump(inner);
    }
}

/// What [`Publisher::shutdown`] left behind.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Summary {
    pub delivered: u64,
    pub queued: usize,
    pub dropped_total: u64,
}

/// The MQTT output.
pub struct Publisher {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl Publisher {
    /// Opens the outbox on `journal_dir` (the daemon's journal, whose next sequence number is
    /// `journal_next`) with its cursor at `cursor_path`, and starts the connection thread. Does
    /// not wait for the broker: an unreachable broker only delays delivery.
    pub fn start(
        cfg: &MqttSection,
        journal_dir: &Path,
        journal_next: u64,
        cursor_path: &Path,
    ) -> anyhow::Result<(Publisher, Opened)> {
        let limits = Limits {
            max_messages: cfg.queue_max_messages,
            max_bytes: (cfg.queue_max_mib * 1024.0 * 1024.0) as usize,
        };
        let (outbox, opened) = Outbox::open(journal_dir, journal_next, cursor_path, limits)
            .context("mqtt.cursor_file")?;
        let topic_base = format!("{}/v1/{}/{}/", cfg.topic_prefix, cfg.fleet, cfg.client_id);
        let mut opts = MqttOptions::new(cfg.client_id.clone(), cfg.host.clone(), cfg.port());
        opts.set_keep_alive(Duration::from_secs(cfg.keep_alive_s))
            .set_clean_start(true)
            .set_connection_timeout(CONNECT_TIMEOUT_S)
            .set_last_will(LastWill::new(
                format!("{topic_base}status"),
                status_payload(&cfg.client_id, "offline", Some("lost")),
                QoS::AtLeastOnce,
                true,
                None,
            ));
        match cfg.transport() {
            Some(Transport::Tcp) => {}
            _ => {
                let tls = super::tls::client_config(cfg)?;
                opts.set_transport(rumqttc::Transport::tls_with_config(
                    rumqttc::TlsConfiguration::Rustls(tls),
                ));
            }
        }
        let (client, conn) = Client::new(opts, 16);
        let qos = match cfg.qos {
            0 => QoS::AtMostOnce,
            2 => QoS::ExactlyOnce,
            _ => QoS::AtLeastOnce,
        };
        let shared = Arc::new(Shared {
            inner: Mutex::new(Inner {
                outbox,
                connected: false,
                inflight: None,
                handed: VecDeque::new(),
                delivered: 0,
                refilled: 0,
            }),
            stop: AtomicBool::new(false),
            durable: AtomicU64::new(0),
            client,
            qos,
            topic_base,
            vehicle: cfg.client_id.clone(),
            estimate_expiry_s: cfg.estimate_expiry_s,
        });
        let th = {
            let shared = shared.clone();
            let cfg = cfg.clone();
            std::thread::Builder::new()
                .name("mqtt".into())
                .spawn(move || connection_loop(&shared, conn, &cfg))?
        };
        Ok((
            Publisher {
                shared,
                thread: Some(th),
            },
            opened,
        ))
    }

    /// The journal is durable up to record `seq`: its messages up to there may be sent.
    pub fn journal_durable(&self, seq: Option<u64>) {
        if let Some(s) = seq {
            self.shared.durable.fetch_max(s + 1, Ordering::AcqRel);
        }
    }

    /// Messages waiting to be sent (read from the journal so far).
    pub fn queued(&self) -> usize {
        let mut inner = self.shared.lock();
        self.shared.refill(&mut inner);
        inner.outbox.len()
    }

    /// Waits up to `drain` for the queue to empty, says `offline` (retained) when connected,
    /// then stops the connection thread. What is still queued is sent after the next start,
    /// from the journal.
    pub fn shutdown(mut self, drain: Duration) -> Summary {
        let deadline = Instant::now() + drain;
        while Instant::now() < deadline && self.queued() > 0 {
            std::thread::sleep(Duration::from_millis(20));
        }
        {
            let mut inner = self.shared.lock();
            if inner.connected {
                self.shared.status(&mut inner, "offline", Some("stopped"));
            }
        }
        // The offline status goes out before the DISCONNECT (requests are sent in order); give
        // it a moment to be acknowledged.
        let until = Instant::now() + Duration::from_millis(500);
        while Instant::now() < until && {
            let i = self.shared.lock();
            i.connected && !i.handed.is_empty()
        } {
            std::thread::sleep(Duration::from_millis(10));
        }
        self.shared.stop.store(true, Ordering::Relaxed);
        let _ = self.shared.client.try_disconnect();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let inner = self.shared.lock();
        let s = Summary {
            delivered: inner.delivered,
            queued: inner.outbox.len(),
            dropped_total: inner.outbox.dropped(),
        };
        if s.queued > 0 {
            log(format_args!(
                "{} message(s) still queued (cursor {}); they are sent from the journal after the next start",
                s.queued,
                inner.outbox.cursor_path().display()
            ));
        }
        s
    }
}

/// `e` in words: with TLS, what a handshake failure means ([`super::tls::explain`]).
fn describe(e: &ConnectionError, cfg: &MqttSection) -> String {
    if cfg.transport() == Some(Transport::Tcp) {
        return e.to_string();
    }
    if let Some(why) = super::tls::explain(e, cfg) {
        return format!("{why}; {e}");
    }
    match e {
        // Closed by the broker before the TLS handshake ended: no TLS on that port, or a
        // broker that drops clients it refuses without an alert.
        ConnectionError::Tls(rumqttc::TlsError::Io(io))
            if matches!(
                io.kind(),
                std::io::ErrorKind::UnexpectedEof | std::io::ErrorKind::ConnectionReset
            ) =>
        {
            format!(
                "the broker closed the connection during the TLS handshake: it may not speak TLS on port {} (a plain-TCP listener?) or it refused this vehicle's certificate; {e}",
                cfg.port()
            )
        }
        _ => e.to_string(),
    }
}

fn connection_loop(shared: &Shared, mut conn: Connection, cfg: &MqttSection) {
    let where_ = format!(
        "{}:{} ({})",
        cfg.host,
        cfg.port(),
        match cfg.transport() {
            Some(Transport::Tcp) => "plain TCP",
            _ => "TLS",
        }
    );
    let reconnect = Duration::from_secs_f64(cfg.reconnect_s);
    let mut last_unreachable_log: Option<Instant> = None;
    while !shared.stop.load(Ordering::Relaxed) {
        let connected = shared.lock().connected;
        let ev: Result<Event, ConnectionError> = if connected {
            match conn.recv_timeout(POLL) {
                Ok(ev) => ev,
                Err(RecvTimeoutError::Timeout) => {
                    // New journal records since the last event.
                    let mut inner = shared.lock();
                    shared.pump(&mut inner);
                    continue;
                }
                Err(RecvTimeoutError::Disconnected) => return,
            }
        } else {
            // Not connected: this call connects (bounded by CONNECT_TIMEOUT_S).
            match conn.recv() {
                Ok(ev) => ev,
                Err(_) => return,
            }
        };
        let mut inner = shared.lock();
        match ev {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                inner.connected = true;
                // A new (clean) session: whatever was in flight is sent again.
                inner.inflight = None;
                inner.handed.clear();
                shared.refill(&mut inner);
                log(format_args!(
                    "connected to {where_} ({} message(s) queued)",
                    inner.outbox.len()
                ));
                last_unreachable_log = None;
                shared.status(&mut inner, "online", None);
                shared.pump(&mut inner);
            }
            Ok(Event::Outgoing(Outgoing::Publish(pkid))) => {
                let handed = inner.handed.pop_front().flatten();
                if let Some((seq, p)) = inner.inflight.as_mut() {
                    if handed == Some(*seq) {
                        *p = Some(pkid);
                        if shared.qos == QoS::AtMostOnce {
                            let seq = *seq;
                            shared.done(&mut inner, seq);
                        }
                    }
                }
            }
            Ok(Event::Incoming(Packet::PubAck(a))) if shared.qos == QoS::AtLeastOnce => {
                match a.reason {
                    PubAckReason::Success | PubAckReason::NoMatchingSubscribers => {
                        shared.acked(&mut inner, a.pkid)
                    }
                    // Refused (e.g. not authorized for the topic): not delivered. It stays in
                    // flight, and so at the front, until the next connection sends it again.
                    r => {
                        if matches!(inner.inflight, Some((_, Some(p))) if p == a.pkid) {
                            log(format_args!(
                                "the broker refused a message ({r:?}); kept, sent again after the next connect"
                            ));
                        }
                    }
                }
            }
            Ok(Event::Incoming(Packet::PubComp(c))) if shared.qos == QoS::ExactlyOnce => {
                shared.acked(&mut inner, c.pkid);
            }
            Ok(_) => {}
            Err(e) => {
                let was = inner.connected;
                inner.connected = false;
                inner.inflight = None;
                inner.handed.clear();
                let queued = inner.outbox.len();
                drop(inner);
                if shared.stop.load(Ordering::Relaxed) {
                    return;
                }
                if was || last_unreachable_log.is_none_or(|t| t.elapsed() >= UNREACHABLE_LOG_EVERY)
                {
                    log(format_args!(
                        "broker {where_} unreachable ({}); {queued} message(s) queued, retrying every {:.1} s",
                        describe(&e, cfg),
                        reconnect.as_secs_f64()
                    ));
                    last_unreachable_log = Some(Instant::now());
                }
                let until = Instant::now() + reconnect;
                while Instant::now() < until && !shared.stop.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(20).min(reconnect));
                }
            }
        }
    }
}
