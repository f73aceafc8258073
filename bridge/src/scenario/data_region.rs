//! The data-region keys scenario tables share, declared once: the initial-state box of
//! `[collect]` and of each `[[sims]]` entry (`x0_low`/`x0_high` or `x0_center`/`x0_radius`,
//! [`with_x0_box!`]), how a table's box is resolved and checked without the simulator
//! ([`x0_box_of`]), and the check of input bounds as a table gives them (`[collect] policy`
//! `low`/`high`, `[[sims]]` `u_low`/`u_high`: [`check_bounds`]). `[collect]` has no
//! `u_low`/`u_high` (its bounds are the policy's), so the shared declaration is the box's four
//! keys.
//!
//! Why a macro and not one struct flattened into both tables: `#[serde(flatten)]` does not work
//! with `#[serde(deny_unknown_fields)]`, so a flattened struct would need a catch-all of the
//! other keys refused by hand, with a hand-kept list of each table's valid keys for the message;
//! it would change serde's messages, move toml's error position from the bad key to its table,
//! and route the box's values through serde's buffered content. [`with_x0_box!`] instead writes
//! the four fields (docs and serde attributes) into each table's own struct, which keeps
//! `deny_unknown_fields` with serde's own message (`unknown field `k`, expected one of …`,
//! naming every valid key of that table) and the serialised form — the same fields in the same
//! order, as echoed into report.json and hashed into the data-reuse key
//! (`orchestrator::reuse::collect_key`) — exactly as they were.

use crate::error::{Error, Result};
use crate::messages::InputBound;

/// Declares a scenario table's struct with the optional initial-state box keys `x0_low`,
/// `x0_high`, `x0_center` and `x0_radius` where the marker `@x0_box("…"),` stands among its
/// fields (the string says what the box means in that table and opens `x0_low`'s doc), and
/// `x0_box_in` and `x0_keys` on it. Every field of the struct is `pub` and ends with a comma.
macro_rules! with_x0_box {
    (
        $(#[$attr:meta])*
        pub struct $name:ident {
            $( $(#[$fa:meta])* pub $f:ident : $ft:ty, )*
            @x0_box($what:literal),
            $( $(#[$ga:meta])* pub $g:ident : $gt:ty, )*
        }
    ) => {
        $(#[$attr])*
        pub struct $name {
            $( $(#[$fa])* pub $f: $ft, )*
            #[doc = $what]
            ///
            /// Lower corner of the initial-state box (`nx` values), with `x0_high`.
            #[serde(default, skip_serializing_if = "Option::is_none")]
            pub x0_low: Option<Vec<f64>>,
            /// Upper corner of the initial-state box (`nx` values), with `x0_low`.
            #[serde(default, skip_serializing_if = "Option::is_none")]
            pub x0_high: Option<Vec<f64>>,
            /// The centre of the initial-state box (`nx` values), with `x0_radius`; instead of
            /// `x0_low`/`x0_high`.
            #[serde(default, skip_serializing_if = "Option::is_none")]
            pub x0_center: Option<Vec<f64>>,
            /// The half-widths of the initial-state box around `x0_center`: one value for every
            /// state or `nx` values (≥ 0).
            #[serde(default, skip_serializing_if = "Option::is_none")]
            pub x0_radius: Option<$crate::messages::InputBound>,
            $( $(#[$ga])* pub $g: $gt, )*
        }

        impl $name {
            /// The initial-state box `(low, high)` this table gives, if any, checked without the
            /// simulator as `x0_box_of` in `scenario/data_region.rs` does; errors begin with
            /// `table`.
            pub fn x0_box_in(
                &self,
                table: &str,
            ) -> $crate::error::Result<Option<(Vec<f64>, Vec<f64>)>> {
                $crate::scenario::data_region::x0_box_of(
                    table,
                    [&self.x0_low, &self.x0_high, &self.x0_center],
                    &self.x0_radius,
                )
            }

            /// The keys this table's initial-state box comes from (for messages):
            /// `x0_low`/`x0_high`, or `x0_center` for both sides.
            pub fn x0_keys(&self) -> [&'static str; 2] {
                if self.x0_center.is_some() {
                    ["x0_center", "x0_center"]
                } else {
                    ["x0_low", "x0_high"]
                }
            }
        }
    };
}
pub(crate) use with_x0_box;

/// An initial-state box given in scenario table `table` as `[x0_low, x0_high, x0_center]` and
/// `x0_radius`: `x0_low`/`x0_high` as given, or `x0_center ± x0_radius`; `None` without
/// either. Checked without the simulator: the keys of one form together and not both forms,
/// equal lengths, finite values, `low ≤ high` (a radius ≥ 0); the length against the
/// simulator's `nx` is checked with its `info` ([`crate::collect::check_x0_box`]).
pub(crate) fn x0_box_of(
    table: &str,
    [x0_low, x0_high, x0_center]: [&Option<Vec<f64>>; 3],
    x0_radius: &Option<InputBound>,
) -> Result<Option<(Vec<f64>, Vec<f64>)>> {
    fn fail<T>(table: &str, m: String) -> Result<T> {
        Err(Error::Config(format!("{table}: {m}")))
    }
    let finite = |what: &str, v: &[f64]| match v.iter().position(|x| !x.is_finite()) {
        Some(i) => fail(table, format!("{what}[{i}] is {} (must be finite)", v[i])),
        None => Ok(()),
    };
    let boxed = x0_low.is_some() || x0_high.is_some();
    let around = x0_center.is_some() || x0_radius.is_some();
    let (lo, hi) = match (boxed, around) {
        (false, false) => return Ok(None),
        (true, true) => {
            return fail(
                table,
                "give the initial-state box either as x0_low and x0_high or as x0_center and \
                 x0_radius, not both"
                    .into(),
            )
        }
        (true, false) => match (x0_low, x0_high) {
            (Some(lo), Some(hi)) => {
                finite("x0_low", lo)?;
                finite("x0_high", hi)?;
                (lo.clone(), hi.clone())
            }
            _ => {
                return fail(
                    table,
                    "x0_low and x0_high go together (the box's two corners)".into(),
                )
            }
        },
        (false, true) => {
            let (Some(c), Some(r)) = (x0_center, x0_radius) else {
                return fail(table, "x0_center and x0_radius go together".into());
            };
            finite("x0_center", c)?;
            let Some(r) = r.resolve(c.len()) else {
                return fail(
                    table,
                    format!(
                        "x0_radius must have 1 value or one per state ({}, as x0_center)",
                        c.len()
                    ),
                );
            };
            finite("x0_radius", &r)?;
            if let Some(i) = r.iter().position(|&v| v < 0.0) {
                return fail(table, format!("x0_radius[{i}] is {} (must be ≥ 0)", r[i]));
            }
            (
                c.iter().zip(&r).map(|(c, r)| c - r).collect(),
                c.iter().zip(&r).map(|(c, r)| c + r).collect(),
            )
        }
    };
    if lo.len() != hi.len() {
        return fail(
            table,
            format!("x0_low has {} values and x0_high {}", lo.len(), hi.len()),
        );
    }
    if let Some(i) = (0..lo.len()).find(|&i| lo[i] > hi[i]) {
        return fail(
            table,
            format!(
                "x0_low[{i}] = {} > x0_high[{i}] = {} (the box is empty)",
                lo[i], hi[i]
            ),
        );
    }
    Ok(Some((lo, hi)))
}

/// Input bounds as scenario table `table` gives them under the keys `keys` (`["`low`",
/// "`high`"]` of `[collect] policy`, `["u_low", "u_high"]` of `[[sims]]`): finite, `low ≤ high`
/// where both are given (a single value against every value of the other side), and lengths
/// that fit each other; their length against `nu` is checked with the simulator's `info`.
pub(crate) fn check_bounds(
    table: &str,
    [lo_key, hi_key]: [&str; 2],
    low: &Option<InputBound>,
    high: &Option<InputBound>,
) -> Result<()> {
    let values = |b: &Option<InputBound>| match b {
        Some(InputBound::All(v)) => vec![*v],
        Some(InputBound::Each(v)) => v.clone(),
        None => Vec::new(),
    };
    let bad = |m: String| Err(Error::Config(format!("{table}: {m}")));
    let (lo, hi) = (values(low), values(high));
    if let Some(v) = lo.iter().chain(&hi).find(|v| !v.is_finite()) {
        return bad(format!("{lo_key} and {hi_key} must be finite, got {v}"));
    }
    let pairs: Vec<(f64, f64)> = match (lo.len(), hi.len()) {
        (0, _) | (_, 0) => Vec::new(),
        (1, _) => hi.iter().map(|&h| (lo[0], h)).collect(),
        (_, 1) => lo.iter().map(|&l| (l, hi[0])).collect(),
        (a, b) if a == b => lo.iter().copied().zip(hi.iter().copied()).collect(),
        (a, b) => return bad(format!("{lo_key} has {a} values and {hi_key} {b}")),
    };
    if let Some((l, h)) = pairs.iter().find(|(l, h)| l > h) {
        return bad(format!("{lo_key} {l} > {hi_key} {h}"));
    }
    Ok(())
}
