//! Checksums against real frames: the VW MQB CRC-8 on every VW frame of the shared opendbc
//! checksum sample, and the Toyota checksum on the real RAV4 log, including that a single flipped
//! bit anywhere in a frame is caught.

mod signals_common;

use shimmy::shared_data::require_file;
use shimmy::signals::checksum::{toyota_checksum, vw_mqb_crc8, ChecksumKind};

use signals_common::hex;

#[test]
fn vw_mqb_crc_matches_every_real_vw_frame() {
    let Some(p) = require_file("checksums/opendbc_checksum_sample_frames.json") else {
        return;
    };
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
    let mut checked = 0;
    let mut messages = 0;
    for entry in v.as_array().unwrap() {
        if entry["dbc"] != "vw_mqb" {
            continue;
        }
        messages += 1;
        let id = entry["address"].as_u64().unwrap() as u32;
        let name = entry["message"].as_str().unwrap();
        for f in entry["frames"].as_array().unwrap() {
            let d = hex(f.as_str().unwrap());
            assert_eq!(
                vw_mqb_crc8(id, &d),
                Some(d[0]),
                "{name} (0x{id:03X}) frame {}",
                f.as_str().unwrap()
            );
            // Any single flipped bit (outside the CRC byte itself, which then simply mismatches)
            // must be caught: CRC-8 detects every single-bit error.
            for bit in 0..d.len() * 8 {
                let mut bad = d.clone();
                bad[bit / 8] ^= 1 << (bit % 8);
                assert!(
                    ChecksumKind::VwMqb.verify(id, &bad).is_err(),
                    "{name}: flipped bit {bit} not caught"
                );
            }
            checked += 1;
        }
    }
    assert_eq!(messages, 23);
    assert_eq!(checked, 368, "the sample holds 368 VW MQB frames");
}

/// (id, payload) of the RAV4 log's frames with the IDs asked for.
fn rav4_frames(ids: &[u32]) -> Option<Vec<(u32, Vec<u8>)>> {
    let p = require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log")?;
    let frames = signals_common::log_frames(&p);
    Some(
        frames
            .iter()
            .filter(|f| ids.contains(&f.id))
            .map(|f| (f.id, f.payload().to_vec()))
            .collect(),
    )
}

#[test]
fn toyota_checksum_holds_on_rav4_steering_and_speed_frames() {
    let Some(frames) = rav4_frames(&[0x025, 0x0B4, 0x024]) else {
        return;
    };
    let mut per_id = std::collections::BTreeMap::new();
    for (id, d) in &frames {
        assert_eq!(toyota_checksum(*id, d), Some(d[7]), "0x{id:03X} {d:02X?}");
        *per_id.entry(*id).or_insert(0) += 1;
        for bit in 0..64 {
            let mut bad = d.clone();
            bad[bit / 8] ^= 1 << (bit % 8);
            assert!(
                ChecksumKind::Toyota.verify(*id, &bad).is_err(),
                "0x{id:03X}: flipped bit {bit} not caught"
            );
        }
    }
    // Every frame of these IDs in the one-minute log.
    assert_eq!(per_id.get(&0x025), Some(&4974));
    assert_eq!(per_id.get(&0x0B4), Some(&2487));
    assert_eq!(per_id.get(&0x024), Some(&4974));
}

#[test]
fn rav4_wheel_speed_and_brake_frames_carry_no_toyota_checksum() {
    // On this RAV4, 0x0AA's last byte is wheel-speed data and 0x224's is brake data: a mapping
    // must not name a checksum for them. The match rate is what chance gives (about 1/256).
    let Some(frames) = rav4_frames(&[0x0AA, 0x224]) else {
        return;
    };
    let n_aa = frames.iter().filter(|(id, _)| *id == 0x0AA).count();
    let n_224 = frames.len() - n_aa;
    assert_eq!((n_aa, n_224), (4974, 2487));
    let ok_aa = frames
        .iter()
        .filter(|(id, d)| *id == 0x0AA && toyota_checksum(*id, d) == Some(d[7]))
        .count();
    let ok_224 = frames
        .iter()
        .filter(|(id, d)| *id == 0x224 && toyota_checksum(*id, d) == Some(d[7]))
        .count();
    assert!(ok_aa < n_aa / 50, "0x0AA: {ok_aa} of {n_aa} match");
    assert_eq!(ok_224, 0);
}
