//! Bounds for the numeric values of every binary's command line, in one place: each
//! function returns a parser for clap's `value_parser` that accepts a number only when it
//! is finite and within the flag's range, so `NaN`, `inf`, `-1` or `1e300` end the program
//! with clap's error naming the flag (`invalid value 'inf' for '--phase-timeout-s <S>':
//! …`) instead of a panic somewhere later (`Duration::from_secs_f64(inf)`).
//!
//! ```
//! use shm_schemas::cli_bounds::{f64_within, int_within};
//!
//! // In a clap derive: `#[arg(long, default_value_t = 90.0,
//! //     value_parser = f64_within(0.001, 86_400.0), allow_negative_numbers = true)]`
//! let phase_timeout_s = f64_within(0.001, 86_400.0);
//! assert_eq!(phase_timeout_s("90"), Ok(90.0));
//! for bad in ["NaN", "inf", "-1", "1e300"] {
//!     assert!(phase_timeout_s(bad).is_err());
//! }
//! let workers = int_within(1usize, 256);
//! assert!(workers("0").is_err() && workers("2").is_ok());
//! ```
//!
//! Negative numbers reach the parser (and its clear error) only with clap's
//! `allow_negative_numbers = true` on the flag; without it clap takes `-1` for a flag of its
//! own and says "unexpected argument '-1' found", which does not name the flag: every
//! numeric flag sets it.

use std::fmt::Display;
use std::str::FromStr;

/// Why a command-line number was refused (clap prints it after the flag's name).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CliBoundError {
    /// Not a number of the flag's type.
    #[error("{value:?} is not a number ({expected})")]
    NotANumber {
        /// The text given.
        value: String,
        /// What was expected, e.g. "an integer".
        expected: &'static str,
    },
    /// `NaN` or an infinity.
    #[error("{value:?} is not a finite number")]
    NotFinite {
        /// The text given.
        value: String,
    },
    /// Outside the flag's range.
    #[error("{value} is out of range: must be within {min}..={max}")]
    OutOfRange {
        /// The value given.
        value: String,
        /// The smallest allowed.
        min: String,
        /// The largest allowed.
        max: String,
    },
}

/// A parser of finite `f64` values within `min..=max`.
pub fn f64_within(
    min: f64,
    max: f64,
) -> impl Fn(&str) -> Result<f64, CliBoundError> + Clone + Send + Sync + 'static {
    move |s: &str| parse_f64(s, min, max)
}

/// A parser of finite `f32` values within `min..=max`.
pub fn f32_within(
    min: f32,
    max: f32,
) -> impl Fn(&str) -> Result<f32, CliBoundError> + Clone + Send + Sync + 'static {
    // Compared as f32 and shown as f32: `0.05` is the bound the user reads and may type
    // (as f64 it would be 0.05000000074505806, refusing its own "0.05").
    move |s: &str| {
        let v = parse_f64(s, f64::MIN, f64::MAX)? as f32;
        if !(min..=max).contains(&v) {
            return Err(CliBoundError::OutOfRange {
                value: s.trim().to_owned(),
                min: min.to_string(),
                max: max.to_string(),
            });
        }
        Ok(v)
    }
}

/// A parser of comma-separated lists of finite `f64` values, each within `min..=max`.
pub fn f64_list_within(
    min: f64,
    max: f64,
) -> impl Fn(&str) -> Result<Vec<f64>, CliBoundError> + Clone + Send + Sync + 'static {
    move |s: &str| s.split(',').map(|v| parse_f64(v, min, max)).collect()
}

/// A parser of integers within `min..=max` (any integer type).
pub fn int_within<T>(
    min: T,
    max: T,
) -> impl Fn(&str) -> Result<T, CliBoundError> + Clone + Send + Sync + 'static
where
    T: FromStr + PartialOrd + Display + Copy + Send + Sync + 'static,
{
    move |s: &str| {
        let t = s.trim();
        let v: T = t.parse().map_err(|_| {
            if t.parse::<f64>().is_ok_and(|f| !f.is_finite()) {
                CliBoundError::NotFinite { value: s.into() }
            } else {
                CliBoundError::NotANumber {
                    value: s.into(),
                    expected: "an integer",
                }
            }
        })?;
        if v < min || v > max {
            return Err(CliBoundError::OutOfRange {
                value: t.to_owned(),
                min: min.to_string(),
                max: max.to_string(),
            });
        }
        Ok(v)
    }
}

fn parse_f64(s: &str, min: f64, max: f64) -> Result<f64, CliBoundError> {
    let v: f64 = s.trim().parse().map_err(|_| CliBoundError::NotANumber {
        value: s.into(),
        expected: "a decimal number",
    })?;
    if !v.is_finite() {
        return Err(CliBoundError::NotFinite { value: s.into() });
    }
    if !(min..=max).contains(&v) {
        return Err(CliBoundError::OutOfRange {
            value: s.trim().to_owned(),
            min: min.to_string(),
            max: max.to_string(),
        });
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floats_must_be_finite_and_within_the_range() {
        let p = f64_within(0.0, 100.0);
        assert_eq!(p("0"), Ok(0.0));
        assert_eq!(p(" 42.5 "), Ok(42.5));
        assert_eq!(p("100"), Ok(100.0));
        for bad in ["NaN", "nan", "inf", "-inf", "infinity"] {
            assert!(
                matches!(p(bad), Err(CliBoundError::NotFinite { .. })),
                "{bad}"
            );
        }
        for bad in ["-1", "1e300", "100.0001"] {
            let e = p(bad).unwrap_err();
            assert!(matches!(e, CliBoundError::OutOfRange { .. }), "{bad}");
            assert!(
                e.to_string().starts_with(&format!("{bad} is out of range")),
                "{e}"
            );
            assert!(e.to_string().contains("0..=100"), "{e}");
        }
        assert!(matches!(p("ten"), Err(CliBoundError::NotANumber { .. })));
        assert_eq!(f32_within(0.0, 1.0)("0.5"), Ok(0.5));
        assert!(f32_within(0.0, 1.0)("1e40").is_err());
        // f32 bounds are shown and compared as f32: the shown minimum itself is accepted.
        assert_eq!(f32_within(0.05, 1.0)("0.05"), Ok(0.05));
        let e = f32_within(0.05, 1.0)("1.5").unwrap_err().to_string();
        assert!(e.contains("0.05..=1"), "{e}");
        let l = f64_list_within(-1.0, 1.0);
        assert_eq!(l("0.1,-0.2"), Ok(vec![0.1, -0.2]));
        assert!(l("0.1,NaN").is_err());
    }

    #[test]
    fn integers_must_be_within_the_range() {
        let p = int_within(1usize, 64);
        assert_eq!(p("1"), Ok(1));
        assert_eq!(p("64"), Ok(64));
        assert!(matches!(p("0"), Err(CliBoundError::OutOfRange { .. })));
        assert!(matches!(p("65"), Err(CliBoundError::OutOfRange { .. })));
        assert!(matches!(p("-1"), Err(CliBoundError::NotANumber { .. })));
        assert!(matches!(p("inf"), Err(CliBoundError::NotFinite { .. })));
        assert!(matches!(p("NaN"), Err(CliBoundError::NotFinite { .. })));
        assert!(p("99999999999999999999999").is_err());
        let s = int_within(-5i32, 5);
        assert_eq!(s("-5"), Ok(-5));
        assert!(s("-6").is_err());
    }
}
