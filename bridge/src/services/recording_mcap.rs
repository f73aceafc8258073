//! A recorded state stream as an MCAP file (the container Foxglove and the ROS 2 tools open):
//! states, inputs and the reference as JSON messages on one channel each, every channel with a
//! JSON schema. The `.npz` beside it stays the training format.

use std::collections::BTreeMap;
use std::io::Cursor;

use serde_json::{json, Map, Value};

use crate::codec::StateMsg;
use crate::error::{Error, ErrorCode, Result};
use crate::messages::SimInfo;

/// What goes into one MCAP file.
pub struct McapRecording<'a> {
    /// The simulator id (topics are `/koopbridge/{sim}/state|input|reference`).
    pub sim: &'a str,
    /// The simulator's info (names, `dt`).
    pub info: &'a SimInfo,
    /// The received states, in arrival order.
    pub states: &'a [StateMsg],
    /// The reference: `nx` values (constant) or rows of `nx` (row `k` at step `k`, the last
    /// repeated past the end); `None`: no reference channel.
    pub reference: Option<&'a [f64]>,
}

/// The JSON schema of a message with integer `k`, number `t`, array `key` of `names.len()`
/// numbers and object `named` with one number per name.
fn schema(title: &str, key: &str, named: &str, names: &[String]) -> Vec<u8> {
    let props: Map<String, Value> = names
        .iter()
        .map(|n| (n.clone(), json!({"type": "number"})))
        .collect();
    let s = json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": {
            "seq": {"type": "integer", "description": "publication sequence number"},
            "k": {"type": "integer", "description": "step index"},
            "t": {"type": "number", "description": "simulation time, s"},
            key: {"type": "array", "items": {"type": "number"}, "minItems": names.len(), "maxItems": names.len()},
            named: {"type": "object", "properties": props},
        },
        "required": ["seq", "k", "t", key, named],
    });
    s.to_string().into_bytes()
}

fn message(
    seq: u64,
    k: u64,
    t: f64,
    key: &str,
    named: &str,
    names: &[String],
    v: &[f64],
) -> Vec<u8> {
    let by_name: Map<String, Value> = names
        .iter()
        .zip(v)
        .map(|(n, x)| (n.clone(), json!(x)))
        .collect();
    json!({"seq": seq, "k": k, "t": t, key: v, named: by_name})
        .to_string()
        .into_bytes()
}

fn mcap_err(e: impl std::fmt::Display) -> Error {
    Error::protocol(ErrorCode::Internal, format!("writing MCAP: {e}"))
}

/// Checks a reference against `nx`: `nx` values or whole rows of `nx` (`dimension` otherwise),
/// all finite (`bad_request`).
pub fn check_reference(r: &[f64], nx: usize) -> Result<()> {
    if nx == 0 || r.is_empty() || r.len() % nx != 0 {
        return Err(Error::protocol(
            ErrorCode::Dimension,
            format!(
                "reference has {} values: expected rows of nx = {nx}",
                r.len()
            ),
        ));
    }
    if !r.iter().all(|v| v.is_finite()) {
        return Err(Error::protocol(
            ErrorCode::BadRequest,
            "reference must be finite",
        ));
    }
    Ok(())
}

/// The MCAP bytes of `rec` (uncompressed chunks). Log and publish times are `seq · dt` in
/// nanoseconds (the stream's own clock: gapless at the sender, monotonic across resets). Each
/// state `k` gives a `state` message; each state after a step also an `input` message for the
/// input held over `[t_{k-1}, t_k)` (logged at `seq - 1`, with `k - 1`); with a reference, a
/// `reference` message per state (its row `k`).
pub fn mcap_bytes(rec: &McapRecording<'_>) -> Result<Vec<u8>> {
    let info = rec.info;
    let nx = info.nx();
    if let Some(r) = rec.reference {
        check_reference(r, nx)?;
    }
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .profile("")
        .create(Cursor::new(Vec::new()))
        .map_err(mcap_err)?;
    let meta = BTreeMap::from([
        ("env".to_string(), info.env.clone()),
        ("dt".to_string(), info.dt.to_string()),
    ]);
    let topic = |leaf: &str| format!("/koopbridge/{}/{leaf}", rec.sim);
    let mut channel = |leaf: &str, title: &str, key: &str, named: &str, names: &[String]| {
        let s = w
            .add_schema(title, "jsonschema", &schema(title, key, named, names))
            .map_err(mcap_err)?;
        w.add_channel(s, &topic(leaf), "json", &meta)
            .map_err(mcap_err)
    };
    let state_ch = channel("state", "koopbridge.State", "x", "state", &info.state_names)?;
    let input_ch = channel("input", "koopbridge.Input", "u", "input", &info.input_names)?;
    let ref_ch = match rec.reference {
        Some(_) => Some(channel(
            "reference",
            "koopbridge.Reference",
            "x_ref",
            "reference",
            &info.state_names,
        )?),
        None => None,
    };
    let ns = |seq: u64| (seq as f64 * info.dt * 1e9).round() as u64;
    let mut put = |channel_id: u16, sequence: u32, time: u64, data: &[u8]| {
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id,
                sequence,
                log_time: time,
                publish_time: time,
            },
            data,
        )
        .map_err(mcap_err)
    };
    for (i, s) in rec.states.iter().enumerate() {
        let n = i as u32;
        if !s.u.is_empty() && s.seq > 0 && s.k > 0 {
            let t = s.t - info.dt;
            let m = message(s.seq - 1, s.k - 1, t, "u", "input", &info.input_names, &s.u);
            put(input_ch, n, ns(s.seq - 1), &m)?;
        }
        let m = message(s.seq, s.k, s.t, "x", "state", &info.state_names, &s.x);
        put(state_ch, n, ns(s.seq), &m)?;
        if let (Some(ch), Some(r)) = (ref_ch, rec.reference) {
            let rows = r.len() / nx;
            let row = (s.k as usize).min(rows - 1);
            let v = &r[row * nx..(row + 1) * nx];
            let m = message(s.seq, s.k, s.t, "x_ref", "reference", &info.state_names, v);
            put(ch, n, ns(s.seq), &m)?;
        }
    }
    w.finish().map_err(mcap_err)?;
    Ok(w.into_inner().into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stream() -> (SimInfo, Vec<StateMsg>) {
        let sys = koopman::systems::by_name("damped-pendulum").unwrap();
        let info = SimInfo::from_system(sys.as_ref());
        let states = (0..4u64)
            .map(|k| StateMsg {
                seq: k,
                k,
                t: k as f64 * info.dt,
                x: vec![k as f64, -(k as f64)],
                u: if k == 0 { vec![] } else { vec![0.5 * k as f64] },
            })
            .collect();
        (info, states)
    }

    #[test]
    fn states_inputs_and_reference_read_back() {
        let (info, states) = stream();
        let reference = [0.0, 0.0, 1.0, 0.0];
        let bytes = mcap_bytes(&McapRecording {
            sim: "p",
            info: &info,
            states: &states,
            reference: Some(&reference),
        })
        .unwrap();
        assert_eq!(&bytes[..8], b"\x89MCAP0\r\n");
        let mut by_topic: BTreeMap<String, Vec<(u64, Value)>> = BTreeMap::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            assert_eq!(m.channel.message_encoding, "json");
            let schema = m.channel.schema.as_ref().unwrap();
            assert_eq!(schema.encoding, "jsonschema");
            let v: Value = serde_json::from_slice(&m.data).unwrap();
            by_topic
                .entry(m.channel.topic.clone())
                .or_default()
                .push((m.log_time, v));
        }
        let state = &by_topic["/koopbridge/p/state"];
        let input = &by_topic["/koopbridge/p/input"];
        let refs = &by_topic["/koopbridge/p/reference"];
        assert_eq!((state.len(), input.len(), refs.len()), (4, 3, 4));
        assert_eq!(state[2].1["x"], json!([2.0, -2.0]));
        assert_eq!(state[2].1["state"]["theta_dot"], json!(-2.0));
        assert_eq!(state[2].0, (2.0 * info.dt * 1e9).round() as u64);
        // The input that led to state 3 was applied at step 2.
        assert_eq!(
            (input[2].1["k"].clone(), input[2].1["u"].clone()),
            (json!(2), json!([1.5]))
        );
        assert_eq!(input[2].0, state[2].0);
        // Reference rows: row k, the last one past the end.
        assert_eq!(refs[0].1["x_ref"], json!([0.0, 0.0]));
        assert_eq!(refs[3].1["x_ref"], json!([1.0, 0.0]));
    }

    #[test]
    fn a_reference_of_the_wrong_size_is_refused() {
        let (info, states) = stream();
        let rec = |r: &'static [f64]| McapRecording {
            sim: "p",
            info: &info,
            states: &states,
            reference: Some(r),
        };
        let code = |r| match mcap_bytes(&rec(r)) {
            Err(Error::Protocol { code, .. }) => code,
            other => panic!("expected a typed error, got {other:?}"),
        };
        assert_eq!(code(&[1.0, 2.0, 3.0]), ErrorCode::Dimension);
        assert_eq!(code(&[]), ErrorCode::Dimension);
        assert_eq!(code(&[1.0, f64::NAN]), ErrorCode::BadRequest);
    }
}
