//! Which camera a calibration belongs to (issue 30 item 2): the `[camera]` table of a
//! calibration file, and the rules that keep a calibration with its own camera.
//!
//! ```toml
//! [camera]
//! frame_id = "zed_left_camera_frame_optical"   # header.frame_id of the camera's colour images
//! serial = "38492711"                          # optional, for people: not checked
//! calibrated_at = 2026-11-27T12:53:48Z         # RFC 3339 (TOML date-time or string) or unix seconds
//! ```
//!
//! - **Written by `perception calibrate`** (`--frame-id`, `--serial`, `--calibrated-at`,
//!   default now); `perception render` and the exact calibration of `--source synthetic:…`
//!   name the synthetic camera ([`SYNTHETIC_CAMERA_FRAME_ID`]), as does the bundled
//!   `assets/perception/calibration.toml`.
//! - **Validated at load, the field named** ([`CalibrationCamera::validate`]): `frame_id` 1 to
//!   [`MAX_FRAME_ID_LEN`] characters, no whitespace or control characters; `serial`, when
//!   given, likewise up to [`MAX_SERIAL_LEN`]; `calibrated_at` a date-time with its UTC
//!   offset (or unix seconds) from 2000 on and not more than a day ahead of this machine's
//!   clock. A file without `[camera]` (made before this table existed, or by hand) is
//!   refused, and the message says to re-run `perception calibrate` for the camera
//!   ([`crate::calibration::CalibrationError::NoCamera`]): guessing its camera is exactly
//!   what this table exists to stop.
//! - **Used only with its camera** ([`CalibrationCamera::check_use`]): a live camera (the
//!   ROS 2 source) refuses the synthetic camera's calibration at start, and then refuses
//!   every colour image whose `header.frame_id` is not the calibration's `frame_id`
//!   ([`crate::ros2_source`], counted as `wrong_camera`); the synthetic source refuses a
//!   calibration made for any other camera. A `file:` recording carries no frame id, so any
//!   valid calibration is taken (the launcher never drives a real arm from a recording).

use std::fmt;
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Deserializer, Serialize, Serializer};

pub use crate::synthetic::SYNTHETIC_CAMERA_FRAME_ID;

/// Longest accepted `frame_id` (characters).
pub const MAX_FRAME_ID_LEN: usize = 256;

/// Longest accepted `serial` (characters).
pub const MAX_SERIAL_LEN: usize = 64;

/// Earliest accepted `calibrated_at`: 2000-01-01T00:00:00Z (0 is an unset clock, not a date).
pub const EARLIEST_CALIBRATED_AT_UNIX_S: i64 = 946_684_800;

/// How far `calibrated_at` may lie ahead of this machine's clock (s): one day, for clocks
/// of different machines; more is a wrong clock or a typo.
pub const MAX_CALIBRATED_AT_AHEAD_S: i64 = 86_400;

/// The camera a calibration was made for: the `[camera]` table.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationCamera {
    /// The camera's frame id: the `header.frame_id` of its colour images (ROS 2), checked
    /// against every image; [`SYNTHETIC_CAMERA_FRAME_ID`] for the synthetic camera.
    pub frame_id: String,
    /// The camera's serial number, for people reading the file (not checked: images do not
    /// carry it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial: Option<String>,
    /// When the calibration was made.
    pub calibrated_at: CalibratedAt,
}

/// What kind of camera a calibration is about to be used with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraKind {
    /// The synthetic camera (`--source synthetic:…`).
    Synthetic,
    /// A recording (`--source file:…`): images without a frame id.
    Recording,
    /// A live camera (`--source ros2`): its images name their frame id.
    Live,
}

/// Why a `[camera]` table was refused; each message names the field.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CameraIdentityError {
    /// `frame_id` is empty, too long or holds whitespace or control characters.
    #[error(
        "camera.frame_id = {value:?}: {why} (the header.frame_id of the camera's colour images)"
    )]
    FrameId {
        /// The value given.
        value: String,
        /// What is wrong.
        why: &'static str,
    },
    /// `serial` is empty, too long or holds whitespace or control characters.
    #[error("camera.serial = {value:?}: {why}")]
    Serial {
        /// The value given.
        value: String,
        /// What is wrong.
        why: &'static str,
    },
    /// `calibrated_at` is before 2000 or more than a day ahead of this machine's clock.
    #[error("camera.calibrated_at = {value}: {why}")]
    CalibratedAt {
        /// The value given.
        value: CalibratedAt,
        /// What is wrong.
        why: &'static str,
    },
}

/// Why a calibration may not be used with a camera ([`CalibrationCamera::check_use`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CameraUseError {
    /// The synthetic camera's calibration with a live camera.
    #[error(
        "the calibration was made for the synthetic camera (camera.frame_id = {SYNTHETIC_CAMERA_FRAME_ID:?}), \
         not for a live camera: its pose is an imaginary camera's, so it is refused with --source ros2; \
         calibrate the camera with `perception calibrate --image FRAME.png --frame-id FRAME_ID …` \
         (FRAME_ID: the header.frame_id of its colour images; docs/real-arm.md, checklist step 3)"
    )]
    SyntheticWithLive,
    /// Another camera's calibration with the synthetic camera.
    #[error(
        "the calibration was made for camera.frame_id = {frame_id:?}, not for the synthetic camera \
         ({SYNTHETIC_CAMERA_FRAME_ID:?}): the synthetic source takes only its own calibration \
         (leave out --calibration and it is derived exactly)"
    )]
    OtherWithSynthetic {
        /// The calibration's camera.
        frame_id: String,
    },
}

impl CalibrationCamera {
    /// The synthetic camera, calibrated at `calibrated_at`.
    pub fn synthetic(calibrated_at: CalibratedAt) -> Self {
        Self {
            frame_id: SYNTHETIC_CAMERA_FRAME_ID.to_owned(),
            serial: None,
            calibrated_at,
        }
    }

    /// Whether this is the synthetic camera's calibration.
    pub fn is_synthetic(&self) -> bool {
        self.frame_id == SYNTHETIC_CAMERA_FRAME_ID
    }

    /// Checks the fields; `now` bounds `calibrated_at` from above (plus
    /// [`MAX_CALIBRATED_AT_AHEAD_S`]).
    ///
    /// # Errors
    /// [`CameraIdentityError`] naming the field.
    pub fn validate(&self, now: CalibratedAt) -> Result<(), CameraIdentityError> {
        if let Some(why) = id_problem(&self.frame_id, MAX_FRAME_ID_LEN) {
            return Err(CameraIdentityError::FrameId {
                value: self.frame_id.clone(),
                why,
            });
        }
        if let Some(serial) = &self.serial
            && let Some(why) = id_problem(serial, MAX_SERIAL_LEN)
        {
            return Err(CameraIdentityError::Serial {
                value: serial.clone(),
                why,
            });
        }
        let at = self.calibrated_at.unix_s();
        if at < EARLIEST_CALIBRATED_AT_UNIX_S {
            return Err(CameraIdentityError::CalibratedAt {
                value: self.calibrated_at,
                why: "before 2000-01-01: an unset clock, not a calibration date",
            });
        }
        if at > now.unix_s().saturating_add(MAX_CALIBRATED_AT_AHEAD_S) {
            return Err(CameraIdentityError::CalibratedAt {
                value: self.calibrated_at,
                why: "more than a day ahead of this machine's clock",
            });
        }
        Ok(())
    }

    /// Whether this calibration may be used with a camera of `kind`: the synthetic
    /// camera's never with a live camera, another camera's never with the synthetic one;
    /// a recording takes any (it carries no frame id).
    ///
    /// # Errors
    /// [`CameraUseError`].
    pub fn check_use(&self, kind: CameraKind) -> Result<(), CameraUseError> {
        match kind {
            CameraKind::Live if self.is_synthetic() => Err(CameraUseError::SyntheticWithLive),
            CameraKind::Synthetic if !self.is_synthetic() => {
                Err(CameraUseError::OtherWithSynthetic {
                    frame_id: self.frame_id.clone(),
                })
            }
            _ => Ok(()),
        }
    }
}

/// What is wrong with a frame id or serial, if anything.
fn id_problem(s: &str, max_len: usize) -> Option<&'static str> {
    if s.is_empty() {
        Some("must not be empty")
    } else if s.chars().count() > max_len {
        Some("too long")
    } else if s.chars().any(|c| c.is_whitespace() || c.is_control()) {
        Some("must not hold whitespace or control characters")
    } else {
        None
    }
}

/// When a calibration was made: whole seconds since the Unix epoch (UTC).
///
/// Read from TOML as a date-time with its offset (`2026-11-27T12:53:48Z`, native or as a
/// string) or as unix seconds (`1795784028`); written as a native TOML date-time in UTC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct CalibratedAt {
    unix_s: i64,
}

/// A `calibrated_at` value that is neither an RFC 3339 date-time with offset nor unix
/// seconds.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "calibrated_at {0:?}: expected an RFC 3339 date-time with its offset (2026-11-27T12:53:48Z) or unix seconds"
)]
pub struct CalibratedAtParseError(pub String);

impl CalibratedAt {
    /// From seconds since the Unix epoch.
    pub fn from_unix_s(unix_s: i64) -> Self {
        Self { unix_s }
    }

    /// Seconds since the Unix epoch.
    pub fn unix_s(self) -> i64 {
        self.unix_s
    }

    /// This machine's clock, whole seconds.
    pub fn now() -> Self {
        let s = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_secs()).unwrap_or(i64::MAX));
        Self::from_unix_s(s)
    }

    /// Parses an RFC 3339 date-time with its offset or unix seconds (the form of
    /// `perception calibrate --calibrated-at`).
    ///
    /// # Errors
    /// [`CalibratedAtParseError`].
    pub fn parse(s: &str) -> Result<Self, CalibratedAtParseError> {
        let s = s.trim();
        if let Ok(unix_s) = s.parse::<i64>() {
            return Ok(Self::from_unix_s(unix_s));
        }
        s.parse::<toml::value::Datetime>()
            .ok()
            .and_then(|d| Self::from_datetime(&d))
            .ok_or_else(|| CalibratedAtParseError(s.to_owned()))
    }

    /// From a TOML date-time; `None` unless it has a date, a time and an offset.
    pub fn from_datetime(d: &toml::value::Datetime) -> Option<Self> {
        let (date, time, offset) = (d.date?, d.time?, d.offset?);
        let offset_s = match offset {
            toml::value::Offset::Z => 0,
            toml::value::Offset::Custom { minutes } => i64::from(minutes) * 60,
        };
        let days = days_from_civil(
            i64::from(date.year),
            i64::from(date.month),
            i64::from(date.day),
        );
        let secs = days * 86_400
            + i64::from(time.hour) * 3600
            + i64::from(time.minute) * 60
            + i64::from(time.second);
        Some(Self::from_unix_s(secs - offset_s))
    }

    /// As a TOML date-time in UTC (`Z`); `None` outside the years 0..=9999.
    pub fn to_datetime(self) -> Option<toml::value::Datetime> {
        let days = self.unix_s.div_euclid(86_400);
        let secs = self.unix_s.rem_euclid(86_400);
        let (y, m, d) = civil_from_days(days);
        let year = u16::try_from(y).ok().filter(|y| *y <= 9999)?;
        Some(toml::value::Datetime {
            date: Some(toml::value::Date {
                year,
                month: m as u8,
                day: d as u8,
            }),
            time: Some(toml::value::Time {
                hour: (secs / 3600) as u8,
                minute: (secs / 60 % 60) as u8,
                second: (secs % 60) as u8,
                nanosecond: 0,
            }),
            offset: Some(toml::value::Offset::Z),
        })
    }
}

impl fmt::Display for CalibratedAt {
    /// RFC 3339 in UTC, or unix seconds outside the years 0..=9999.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.to_datetime() {
            Some(d) => write!(f, "{d}"),
            None => write!(f, "{} (unix seconds)", self.unix_s),
        }
    }
}

impl Serialize for CalibratedAt {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self.to_datetime() {
            Some(d) => d.serialize(s),
            None => s.serialize_i64(self.unix_s),
        }
    }
}

impl<'de> Deserialize<'de> for CalibratedAt {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(CalibratedAtVisitor)
    }
}

struct CalibratedAtVisitor;

impl<'de> serde::de::Visitor<'de> for CalibratedAtVisitor {
    type Value = CalibratedAt;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("an RFC 3339 date-time with its offset (2026-11-27T12:53:48Z) or unix seconds")
    }

    fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<CalibratedAt, E> {
        Ok(CalibratedAt::from_unix_s(v))
    }

    fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<CalibratedAt, E> {
        i64::try_from(v)
            .map(CalibratedAt::from_unix_s)
            .map_err(|_| E::custom(format!("{v} unix seconds is out of range")))
    }

    fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<CalibratedAt, E> {
        CalibratedAt::parse(v).map_err(E::custom)
    }

    /// A native TOML date-time (the toml crate hands it over as a one-entry map).
    fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<CalibratedAt, A::Error> {
        let d =
            toml::value::Datetime::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
        CalibratedAt::from_datetime(&d).ok_or_else(|| {
            serde::de::Error::custom(format!(
                "{d}: a date-time with its offset is needed (e.g. {d}Z), not a local date or time"
            ))
        })
    }
}

/// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's algorithm).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The date (year, month, day) of a day count since 1970-01-01.
fn civil_from_days(z: i64) -> (i64, i64, i64) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(frame_id: &str) -> CalibrationCamera {
        CalibrationCamera {
            frame_id: frame_id.to_owned(),
            serial: None,
            calibrated_at: CalibratedAt::from_unix_s(1_795_784_028),
        }
    }

    #[test]
    fn calibrated_at_reads_rfc3339_and_unix_seconds_and_writes_utc() {
        let t = CalibratedAt::parse("2026-11-27T12:53:48Z").unwrap();
        assert_eq!(t.unix_s(), 1_795_784_028);
        assert_eq!(t.to_string(), "2026-11-27T12:53:48Z");
        assert_eq!(CalibratedAt::parse("1795784028").unwrap(), t);
        assert_eq!(CalibratedAt::parse("2026-11-27T14:53:48+02:00").unwrap(), t);
        assert_eq!(CalibratedAt::parse("2026-11-27 12:53:48.75Z").unwrap(), t);
        assert_eq!(
            CalibratedAt::from_unix_s(0).to_string(),
            "1970-01-01T00:00:00Z"
        );
        assert_eq!(
            CalibratedAt::parse("2000-02-29T00:00:00Z")
                .unwrap()
                .unix_s(),
            951_782_400
        );
        for bad in [
            "",
            "yesterday",
            "2026-11-27",
            "2026-11-27T12:53:48",
            "12:53:48Z",
        ] {
            let e = CalibratedAt::parse(bad).unwrap_err().to_string();
            assert!(e.contains("RFC 3339"), "{bad:?}: {e}");
        }
        #[derive(Debug, Deserialize, Serialize, PartialEq)]
        struct W {
            calibrated_at: CalibratedAt,
        }
        for text in [
            "calibrated_at = 2026-11-27T12:53:48Z",
            "calibrated_at = \"2026-11-27T12:53:48Z\"",
            "calibrated_at = 1795784028",
            "calibrated_at = 2026-11-27T13:53:48+01:00",
        ] {
            let w: W = toml::from_str(text).unwrap_or_else(|e| panic!("{text}: {e}"));
            assert_eq!(w.calibrated_at, t, "{text}");
        }
        let written = toml::to_string(&W { calibrated_at: t }).unwrap();
        assert_eq!(written.trim(), "calibrated_at = 2026-11-27T12:53:48Z");
        for text in [
            "calibrated_at = 2026-11-27T12:53:48",
            "calibrated_at = 2026-11-27",
            "calibrated_at = \"last week\"",
            "calibrated_at = 1.5",
        ] {
            let e = toml::from_str::<W>(text).unwrap_err().to_string();
            assert!(e.contains("calibrated_at"), "{text}: {e}");
        }
    }

    #[test]
    fn camera_fields_are_validated_naming_the_field() {
        let now = CalibratedAt::from_unix_s(1_795_784_028);
        camera("zed_left_camera_frame_optical")
            .validate(now)
            .unwrap();
        CalibrationCamera::synthetic(now).validate(now).unwrap();
        for (bad, why) in [
            ("", "empty"),
            ("zed left", "whitespace"),
            ("zed\u{0}", "control"),
        ] {
            let e = camera(bad).validate(now).unwrap_err().to_string();
            assert!(e.contains("camera.frame_id") && e.contains(why), "{e}");
        }
        let e = camera(&"x".repeat(MAX_FRAME_ID_LEN + 1))
            .validate(now)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("camera.frame_id") && e.contains("too long"),
            "{e}"
        );
        let mut c = camera("zed");
        c.serial = Some(String::new());
        let e = c.validate(now).unwrap_err().to_string();
        assert!(e.contains("camera.serial"), "{e}");
        c.serial = Some("38492711".into());
        c.validate(now).unwrap();
        c.calibrated_at = CalibratedAt::from_unix_s(0);
        let e = c.validate(now).unwrap_err().to_string();
        assert!(
            e.contains("camera.calibrated_at = 1970-01-01T00:00:00Z") && e.contains("2000"),
            "{e}"
        );
        c.calibrated_at = CalibratedAt::from_unix_s(now.unix_s() + 2 * 86_400);
        let e = c.validate(now).unwrap_err().to_string();
        assert!(
            e.contains("camera.calibrated_at") && e.contains("ahead"),
            "{e}"
        );
        c.calibrated_at = CalibratedAt::from_unix_s(now.unix_s() + 3600);
        c.validate(now).unwrap();
    }

    #[test]
    fn a_calibration_is_used_only_with_its_kind_of_camera() {
        let now = CalibratedAt::from_unix_s(1_795_784_028);
        let synthetic = CalibrationCamera::synthetic(now);
        let zed = camera("zed_left_camera_frame_optical");
        synthetic.check_use(CameraKind::Synthetic).unwrap();
        synthetic.check_use(CameraKind::Recording).unwrap();
        let e = synthetic
            .check_use(CameraKind::Live)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("synthetic camera")
                && e.contains("--source ros2")
                && e.contains("--frame-id"),
            "{e}"
        );
        zed.check_use(CameraKind::Live).unwrap();
        zed.check_use(CameraKind::Recording).unwrap();
        let e = zed
            .check_use(CameraKind::Synthetic)
            .unwrap_err()
            .to_string();
        assert!(e.contains("zed_left_camera_frame_optical"), "{e}");
    }

    #[test]
    fn civil_dates_round_trip() {
        for days in [
            -1_000_000, -719_468, -1, 0, 1, 59, 60, 10_957, 20_419, 2_932_896,
        ] {
            let (y, m, d) = civil_from_days(days);
            assert_eq!(days_from_civil(y, m, d), days, "{y}-{m}-{d}");
        }
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
    }
}
