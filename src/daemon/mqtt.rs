//! The optional MQTT output to a fleet backend: alerts and braking-event
//! summaries, published by an outgoing `rumqttc` client through the crash-safe
//! [`super::outbox::Outbox`], so nothing is lost while the broker is unreachable.
//!
//! What it is: [`Publisher`], which owns one connection thread. [`Publisher::publish`] writes a
//! message to the outbox (fsynced) and returns; the thread sends the outbox's front message,
//! waits for the broker's acknowledgement (QoS 1: PUBACK, QoS 2: PUBCOMP, QoS 0: written to the
//! socket), removes it from the outbox and sends the next one. One message in flight at a time
//! keeps the order strict across reconnects; the rate it allows (one broker round trip per
//! message) is far above the daemon's (a few messages per braking event). When the connection
//! fails, the message in flight stays at the front and is sent again after the reconnect, which
//! is tried every `mqtt.reconnect_s`.
//!
//! Topics: `<topic_prefix>/<client_id>/event` and `<topic_prefix>/<client_id>/alert`. Payload:
//! one JSON object with `id` (`"<client_id>:<seq>"`, unique and increasing, the de-duplication
//! key for at-least-once delivery, see [`super::outbox`]), `seq`, `type`, `queue_dropped` (the
//! outbox's running drop count) and the record itself.
//!
//! What it is not: a listener or a server. It makes one outgoing TCP connection, only when
//! `[mqtt] enabled = true`; no TLS (put a local TLS bridge, e.g. mosquitto's, in front of a
//! remote broker).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Context;
use rumqttc::{
    Client, Connection, ConnectionError, Event, MqttOptions, NetworkOptions, Outgoing, Packet, QoS,
    RecvTimeoutError,
};

use super::config::MqttSection;
use super::outbox::{Limits, Opened, Outbox};

fn log(msg: impl std::fmt::Display) {
    eprintln!("shimmyd: mqtt: {msg}");
}

/// Broker connect timeout (s): also bounds how long a stop can wait for a connect attempt.
const CONNECT_TIMEOUT_S: u64 = 3;
/// While connected, the thread checks the stop flag this often.
const POLL: Duration = Duration::from_millis(200);
/// "Broker unreachable" is logged at the first failure and then at most this often.
const UNREACHABLE_LOG_EVERY: Duration = Duration::from_secs(60);

struct Inner {
    outbox: Outbox,
    connected: bool,
    /// The message sent and not yet acknowledged: (seq, packet id once known).
    inflight: Option<(u64, Option<u16>)>,
    delivered: u64,
}

struct Shared {
    inner: Mutex<Inner>,
    stop: AtomicBool,
    client: Client,
    qos: QoS,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Inner> {
        // A panic in the other thread while holding the lock leaves the outbox consistent on
        // disk (every step is atomic there), so the poisoned guard is still usable.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Sends the front message when connected and nothing is in flight.
    fn pump(&self, inner: &mut Inner) {
        if !inner.connected || inner.inflight.is_some() {
            return;
        }
        let Some(m) = inner.outbox.front() else {
            return;
        };
        match self
            .client
            .try_publish(m.topic.as_str(), self.qos, false, m.payload.as_bytes())
        {
            Ok(()) => inner.inflight = Some((m.seq, None)),
            Err(e) => log(format_args!(
                "cannot hand message {} to the client: {e}",
                m.seq
            )),
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
                "message {seq} delivered but the outbox cursor could not be saved (it will be sent again after a restart): {e:#}"
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
    /// `<topic_prefix>/<client_id>/`.
    topic_base: String,
    client_id: String,
}

impl Publisher {
    /// Opens the outbox in `queue_dir` and starts the connection thread. Does not wait for the
    /// broker: an unreachable broker only delays delivery.
    pub fn start(
        cfg: &MqttSection,
        queue_dir: &std::path::Path,
    ) -> anyhow::Result<(Publisher, Opened)> {
        let limits = Limits {
            max_messages: cfg.queue_max_messages,
            max_bytes: (cfg.queue_max_mib * 1024.0 * 1024.0) as usize,
        };
        let (outbox, opened) = Outbox::open(queue_dir, limits).context("mqtt.queue_dir")?;
        let mut opts = MqttOptions::new(cfg.client_id.clone(), cfg.host.clone(), cfg.port);
        opts.set_keep_alive(Duration::from_secs(cfg.keep_alive_s))
            .set_clean_session(true);
        let (client, mut conn) = Client::new(opts, 16);
        let mut net = NetworkOptions::new();
        net.set_connection_timeout(CONNECT_TIMEOUT_S);
        conn.eventloop.set_network_options(net);
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
                delivered: 0,
            }),
            stop: AtomicBool::new(false),
            client,
            qos,
        });
        let th = {
            let shared = shared.clone();
            let where_ = format!("{}:{}", cfg.host, cfg.port);
            let reconnect = Duration::from_secs_f64(cfg.reconnect_s);
            std::thread::Builder::new()
                .name("mqtt".into())
                .spawn(move || connection_loop(&shared, conn, &where_, reconnect))?
        };
        Ok((
            Publisher {
                shared,
                thread: Some(th),
                topic_base: format!("{}/{}/", cfg.topic_prefix, cfg.client_id),
                client_id: cfg.client_id.clone(),
            },
            opened,
        ))
    }

    /// Queues one message of `kind` (the topic's last level: `event`, `alert`) with `body`'s
    /// fields plus `id`, `seq`, `type` and `queue_dropped`. Returns once it is on disk.
    pub fn publish(&self, kind: &str, body: serde_json::Value) -> anyhow::Result<()> {
        let mut inner = self.shared.lock();
        let seq = inner.outbox.next_seq();
        let mut obj = serde_json::Map::new();
        obj.insert("id".into(), format!("{}:{seq}", self.client_id).into());
        obj.insert("seq".into(), seq.into());
        obj.insert("type".into(), kind.into());
        obj.insert("queue_dropped".into(), inner.outbox.dropped().into());
        match body {
            serde_json::Value::Object(m) => obj.extend(m),
            other => {
                obj.insert("body".into(), other);
            }
        }
        let payload = serde_json::to_string(&obj)?;
        let topic = format!("{}{kind}", self.topic_base);
        let dropped = inner.outbox.push(&topic, payload)?;
        for s in &dropped {
            log(format_args!(
                "outbox full (mqtt.queue_max_messages / queue_max_mib): dropped the oldest queued message {}:{s} ({} dropped in total)",
                self.client_id,
                inner.outbox.dropped()
            ));
        }
        self.shared.pump(&mut inner);
        Ok(())
    }

    /// Messages waiting in the outbox.
    pub fn queued(&self) -> usize {
        self.shared.lock().outbox.len()
    }

    /// Waits up to `drain` for the outbox to empty, then stops the connection thread. What is
    /// still queued stays on disk and is sent after the next start.
    pub fn shutdown(mut self, drain: Duration) -> Summary {
        let deadline = Instant::now() + drain;
        while Instant::now() < deadline && !self.shared.lock().outbox.is_empty() {
            std::thread::sleep(Duration::from_millis(20));
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
                "{} message(s) still queued in {}; they are sent after the next start",
                s.queued,
                inner.outbox.dir().display()
            ));
        }
        s
    }
}

fn connection_loop(shared: &Shared, mut conn: Connection, where_: &str, reconnect: Duration) {
    let mut last_unreachable_log: Option<Instant> = None;
    while !shared.stop.load(Ordering::Relaxed) {
        let connected = shared.lock().connected;
        let ev: Result<Event, ConnectionError> = if connected {
            match conn.recv_timeout(POLL) {
                Ok(ev) => ev,
                Err(RecvTimeoutError::Timeout) => continue,
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
                log(format_args!(
                    "connected to {where_} ({} message(s) queued)",
                    inner.outbox.len()
                ));
                last_unreachable_log = None;
                shared.pump(&mut inner);
            }
            Ok(Event::Outgoing(Outgoing::Publish(pkid))) => {
                if let Some((seq, p)) = inner.inflight.as_mut() {
                    *p = Some(pkid);
                    if shared.qos == QoS::AtMostOnce {
                        let seq = *seq;
                        shared.done(&mut inner, seq);
                    }
                }
            }
            Ok(Event::Incoming(Packet::PubAck(a))) if shared.qos == QoS::AtLeastOnce => {
                shared.acked(&mut inner, a.pkid);
            }
            Ok(Event::Incoming(Packet::PubComp(c))) if shared.qos == QoS::ExactlyOnce => {
                shared.acked(&mut inner, c.pkid);
            }
            Ok(_) => {}
            Err(e) => {
                let was = inner.connected;
                inner.connected = false;
                inner.inflight = None;
                let queued = inner.outbox.len();
                drop(inner);
                if shared.stop.load(Ordering::Relaxed) {
                    return;
                }
                if was || last_unreachable_log.is_none_or(|t| t.elapsed() >= UNREACHABLE_LOG_EVERY)
                {
                    log(format_args!(
                        "broker {where_} unreachable ({e}); {queued} message(s) queued, retrying every {:.1} s",
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
