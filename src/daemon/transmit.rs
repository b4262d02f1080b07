//! SHIMMY_01 of dbc/shimmy_reference.dbc: packs the monitor's status (alert state, events,
//! estimated clearance, last amplitude, confidence) into a frame with counter and CRC-8.
//!
//! What it is: the encoder only. Whether anything is sent is the daemon's decision, and it
//! sends only when `outputs.transmit = true` (read-only is the default).

use anyhow::{anyhow, Context};

use crate::dbc::{Database, Message};
use crate::signals::checksum::ChecksumKind;
use crate::wire::Frame;

/// `SHM_AlertState` values of the DBC's value table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AlertState {
    Init = 0,
    Ok = 1,
    Advisory = 2,
    Warning = 3,
}

pub struct Encoder {
    msg: Message,
    counter: u8,
}

impl Encoder {
    pub fn new(db: &Database) -> anyhow::Result<Encoder> {
        let i = db
            .message_by_name("SHIMMY_01")
            .ok_or_else(|| anyhow!("outputs.transmit: the DBC has no message SHIMMY_01"))?;
        Ok(Encoder {
            msg: db.messages()[i].clone(),
            counter: 0,
        })
    }

    fn put(&self, name: &str, v: f64, data: &mut [u8]) -> anyhow::Result<()> {
        let i = self
            .msg
            .signal_by_name(name)
            .ok_or_else(|| anyhow!("SHIMMY_01 has no signal {name}"))?;
        self.msg.signals[i]
            .encode_phys(v, data)
            .map_err(|e| anyhow!("SHIMMY_01.{name} = {v}: {e:?}"))
    }

    /// The next SHIMMY_01 frame. `None` values are sent as the DBC's NOT_AVAILABLE (4.095).
    pub fn frame(
        &mut self,
        t_ns: i64,
        state: AlertState,
        events: u64,
        clearance_mm: Option<f64>,
        amplitude_deg: Option<f64>,
        confidence_pct: f64,
    ) -> anyhow::Result<Frame> {
        let mut data = [0u8; 8];
        self.put("SHM_AlertState", state as u8 as f64, &mut data)?;
        self.put("SHM_EventCount", events.min(255) as f64, &mut data)?;
        self.put(
            "SHM_Clearance",
            clearance_mm.map_or(4.095, |c| c.clamp(0.0, 4.094)),
            &mut data,
        )?;
        self.put(
            "SHM_Amplitude",
            amplitude_deg.map_or(4.095, |a| a.clamp(0.0, 4.094)),
            &mut data,
        )?;
        self.put(
            "SHM_Confidence",
            confidence_pct.clamp(0.0, 100.0),
            &mut data,
        )?;
        self.put("SHM_Counter", self.counter as f64, &mut data)?;
        self.counter = (self.counter + 1) % 16;
        ChecksumKind::Shimmy
            .apply(self.msg.id, &mut data)
            .map_err(|e| anyhow!("{e}"))
            .context("SHIMMY_01 checksum")?;
        Frame::classic(t_ns, self.msg.id, false, &data)
            .ok_or_else(|| anyhow!("SHIMMY_01 does not fit a classic frame"))
    }
}
