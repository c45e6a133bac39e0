//! The run folder as a rosbag2 bag: `metadata.yaml` beside `run.mcap`, and the QoS each
//! topic's publisher "offered" (what `ros2 bag play` offers again, so a late subscriber to
//! `/robot_description` still gets the URDF).
//!
//! # Format: rosbag2 metadata version 9
//!
//! Version 9 is what ROS 2 Jazzy's `rosbag2` writes itself (its `BagMetadata::version`), and
//! the newest version the `rosbags` Python reader accepts (it reads 1..=9), so one file
//! serves `ros2 bag info/play` and `rosbags.rosbag2.Reader` without translation. Version 9
//! differs from 8 only in the QoS: `offered_qos_profiles` is a YAML list with policy names
//! (`keep_last`, `reliable`, `transient_local`, `automatic`) instead of a string holding a
//! YAML list of enum numbers. Jazzy's reader detects either form; Humble (metadata version
//! 5) expects the string and fails on the list: Humble is not a target. The fields written:
//! `version`, `storage_identifier: mcap`, `duration`, `starting_time`, `message_count`,
//! `topics_with_message_count` (name, type, `serialization_format: cdr`,
//! `offered_qos_profiles`, an empty `type_description_hash`: no RIHS01 hash is computed),
//! `compression_format` and `compression_mode` (empty: not compressed), `relative_file_paths`
//! and `files` (the one `run.mcap`), `custom_data` (`foresight_recording`, see below) and
//! `ros_distro: jazzy` (the distribution whose format and message layouts are followed).
//!
//! Each MCAP channel carries the same profiles as a YAML string under the channel metadata
//! key `offered_qos_profiles` (the `ros2` MCAP profile, as `rosbag2_storage_mcap` writes it):
//! `rosbags` pairs a channel with its `metadata.yaml` topic only when both profiles are equal.
//!
//! # Offered QoS
//!
//! Every topic offers `reliable`, `keep_last`, deadline, lifespan and lease duration
//! unspecified (`0 s 0 ns`: the middleware's default, infinite), liveliness `automatic`.
//! `/robot_description` and `/tf_static` (latched state, as `robot_state_publisher` offers
//! them) are `transient_local` with depth 1; every other topic streams: `volatile`, depth 10.
//!
//! # When `metadata.yaml` is written
//!
//! Only for a recording whose folder is its own ([`crate::RecorderConfig::bag_metadata`]:
//! the launcher's `runs/<id>/`); the channels' QoS is written in every file. Always whole (a
//! temporary file beside it, fsync, rename, fsync of the folder: a reader sees the old file
//! or the new one, never a torn one), twice:
//! - at the start, once `/robot_description` is in the file: every topic with its type and
//!   QoS, the counts so far, `foresight_recording: recording`. A recording killed before it
//!   finishes keeps this file: the folder still names its topics and their QoS, the counts
//!   are those of the start, and `run.mcap` has no summary (the MCAP readers read it up to its
//!   last chunk; `rosbags` needs the footer and refuses it);
//! - at the end, after `run.mcap` is finished and synced: the true counts, start and
//!   duration, `foresight_recording: finished` (or `size_limit` when the size bound stopped
//!   it, or `failed` after a write error).
//!
//! `run.mcap` itself is not renamed into place: it is append-only and always ends at a record
//! boundary ([`crate::mcap_file`]), so a crash leaves a readable prefix under its final name,
//! and the footer is the last thing written (a file with the footer's magic is complete).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs::File;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// The metadata file's name in a bag folder.
pub const METADATA_FILE: &str = "metadata.yaml";

/// The rosbag2 metadata version written (see the [module docs](self)).
pub const METADATA_VERSION: u32 = 9;

/// `ros_distro` of the metadata: the distribution whose formats are followed.
pub const ROS_DISTRO: &str = "jazzy";

/// Topics offered `transient_local` (latched); every other topic is `volatile`.
pub const LATCHED_TOPICS: [&str; 2] = ["/robot_description", "/tf_static"];

/// QoS durability of a publisher.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// Late subscribers get the last `depth` messages (a latched topic).
    TransientLocal,
    /// Only subscribers present at publication get a message.
    Volatile,
}

impl Durability {
    /// The name rosbag2 writes (metadata version 9).
    pub fn name(self) -> &'static str {
        match self {
            Self::TransientLocal => "transient_local",
            Self::Volatile => "volatile",
        }
    }
}

/// The QoS profile a topic's publisher offered: `reliable`, `keep_last(depth)`, liveliness
/// `automatic`, deadline, lifespan and lease duration unspecified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OfferedQos {
    /// `history: keep_last` depth.
    pub depth: u32,
    /// Durability.
    pub durability: Durability,
}

impl OfferedQos {
    /// A latched topic: `transient_local`, depth 1.
    pub const LATCHED: Self = Self {
        depth: 1,
        durability: Durability::TransientLocal,
    };
    /// A streaming topic: `volatile`, depth 10 (rclcpp's default).
    pub const STREAMING: Self = Self {
        depth: 10,
        durability: Durability::Volatile,
    };

    /// The profile `topic` is recorded with: [`Self::LATCHED`] for [`LATCHED_TOPICS`],
    /// [`Self::STREAMING`] otherwise.
    pub fn for_topic(topic: &str) -> Self {
        if LATCHED_TOPICS.contains(&topic) {
            Self::LATCHED
        } else {
            Self::STREAMING
        }
    }

    /// The profile as one item of a YAML block list, each line prefixed by `indent`
    /// (version 9 names). No trailing newline.
    fn yaml_item(self, indent: &str) -> String {
        let mut s = String::new();
        let unspecified = |s: &mut String, key: &str| {
            let _ = write!(
                s,
                "\n{indent}  {key}:\n{indent}    sec: 0\n{indent}    nsec: 0"
            );
        };
        let _ = write!(
            s,
            "{indent}- history: keep_last\n{indent}  depth: {}\n{indent}  reliability: reliable\n{indent}  durability: {}",
            self.depth,
            self.durability.name()
        );
        unspecified(&mut s, "deadline");
        unspecified(&mut s, "lifespan");
        let _ = write!(s, "\n{indent}  liveliness: automatic");
        unspecified(&mut s, "liveliness_lease_duration");
        let _ = write!(s, "\n{indent}  avoid_ros_namespace_conventions: false");
        s
    }

    /// The value of the MCAP channel metadata key `offered_qos_profiles`: a YAML list of this
    /// one profile, as a string.
    pub fn channel_metadata(self) -> String {
        self.yaml_item("")
    }
}

/// One recorded topic: name, ROS type (`pkg/msg/Type`), offered QoS.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagTopic {
    /// Topic name.
    pub name: String,
    /// ROS 2 type name, e.g. `sensor_msgs/msg/JointState` (the MCAP schema's name).
    pub type_name: String,
    /// What its publisher offered.
    pub qos: OfferedQos,
}

/// The state of a recording as `metadata.yaml` records it (`custom_data.foresight_recording`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordingState {
    /// Being written (after a crash the file stays so).
    Recording,
    /// Closed normally.
    Finished,
    /// Stopped by the size bound, closed normally.
    SizeLimit,
    /// A write failed; `run.mcap` is readable up to its last finished chunk.
    Failed,
}

impl RecordingState {
    /// The value written.
    pub fn name(self) -> &'static str {
        match self {
            Self::Recording => "recording",
            Self::Finished => "finished",
            Self::SizeLimit => "size_limit",
            Self::Failed => "failed",
        }
    }
}

/// What was written (the MCAP file's summary, and the bag's metadata of it).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RecordingStats {
    /// Messages written, per topic.
    pub messages: BTreeMap<String, u64>,
    /// Messages not written because the size limit was reached.
    pub dropped_at_limit: u64,
    /// Whether the size limit was reached.
    pub limit_reached: bool,
    /// File size (bytes) when closed.
    pub bytes: u64,
    /// Log time (ns since the Unix epoch) of the first and the last message written.
    pub log_time_span_ns: Option<(u64, u64)>,
}

impl RecordingStats {
    /// All messages written.
    pub fn total(&self) -> u64 {
        self.messages.values().sum()
    }
}

/// What `metadata.yaml` says about a bag of one MCAP file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagMetadata {
    /// The storage file, relative to the bag folder (`run.mcap`).
    pub file_name: String,
    /// Every topic, in channel order.
    pub topics: Vec<BagTopic>,
    /// Messages per topic (a topic missing here has none).
    pub stats: RecordingStats,
    /// The recording's state.
    pub state: RecordingState,
}

/// A double-quoted YAML scalar (YAML 1.2 escapes; the text is kept whole).
fn quoted(text: &str) -> String {
    let mut s = String::with_capacity(text.len() + 2);
    s.push('"');
    for c in text.chars() {
        match c {
            '"' => s.push_str("\\\""),
            '\\' => s.push_str("\\\\"),
            '\n' => s.push_str("\\n"),
            '\t' => s.push_str("\\t"),
            c if (c as u32) < 0x20 || c == '\u{7f}' => {
                let _ = write!(s, "\\x{:02x}", c as u32);
            }
            c => s.push(c),
        }
    }
    s.push('"');
    s
}

impl BagMetadata {
    /// Messages in the bag.
    pub fn message_count(&self) -> u64 {
        self.stats.total()
    }

    /// Start (ns since the Unix epoch) and duration (ns) of the messages; `(0, 0)` when none.
    pub fn time_span_ns(&self) -> (u64, u64) {
        match self.stats.log_time_span_ns {
            Some((first, last)) => (first, last.saturating_sub(first)),
            None => (0, 0),
        }
    }

    /// The whole `metadata.yaml` text (rosbag2 version [`METADATA_VERSION`]).
    pub fn to_yaml(&self) -> String {
        let (start, duration) = self.time_span_ns();
        let count = self.message_count();
        let file = quoted(&self.file_name);
        let mut s = String::new();
        let _ = writeln!(s, "rosbag2_bagfile_information:");
        let _ = writeln!(s, "  version: {METADATA_VERSION}");
        let _ = writeln!(s, "  storage_identifier: mcap");
        let _ = writeln!(s, "  duration:\n    nanoseconds: {duration}");
        let _ = writeln!(s, "  starting_time:\n    nanoseconds_since_epoch: {start}");
        let _ = writeln!(s, "  message_count: {count}");
        if self.topics.is_empty() {
            let _ = writeln!(s, "  topics_with_message_count: []");
        } else {
            let _ = writeln!(s, "  topics_with_message_count:");
        }
        for t in &self.topics {
            let n = self.stats.messages.get(&t.name).copied().unwrap_or(0);
            let _ = writeln!(s, "    - topic_metadata:");
            let _ = writeln!(s, "        name: {}", quoted(&t.name));
            let _ = writeln!(s, "        type: {}", quoted(&t.type_name));
            let _ = writeln!(s, "        serialization_format: cdr");
            let _ = writeln!(s, "        offered_qos_profiles:");
            let _ = writeln!(s, "{}", t.qos.yaml_item("          "));
            let _ = writeln!(s, "        type_description_hash: \"\"");
            let _ = writeln!(s, "      message_count: {n}");
        }
        let _ = writeln!(s, "  compression_format: \"\"");
        let _ = writeln!(s, "  compression_mode: \"\"");
        let _ = writeln!(s, "  relative_file_paths:\n    - {file}");
        let _ = writeln!(s, "  files:");
        let _ = writeln!(s, "    - path: {file}");
        let _ = writeln!(
            s,
            "      starting_time:\n        nanoseconds_since_epoch: {start}"
        );
        let _ = writeln!(s, "      duration:\n        nanoseconds: {duration}");
        let _ = writeln!(s, "      message_count: {count}");
        let _ = writeln!(s, "  custom_data:");
        let _ = writeln!(s, "    foresight_recording: {}", self.state.name());
        let _ = writeln!(s, "  ros_distro: {ROS_DISTRO}");
        s
    }

    /// Writes `dir/metadata.yaml` whole: a temporary file beside it, fsync, rename, fsync
    /// of the folder.
    ///
    /// # Errors
    /// [`BagMetadataWriteError`]: the file keeps its previous content (or is absent).
    pub fn write(&self, dir: &Path) -> Result<PathBuf, BagMetadataWriteError> {
        let path = dir.join(METADATA_FILE);
        let tmp = dir.join(format!(".{METADATA_FILE}.tmp.{}", std::process::id()));
        let io = |source| BagMetadataWriteError {
            path: path.clone(),
            source,
        };
        let written = File::create(&tmp).and_then(|mut f| {
            f.write_all(self.to_yaml().as_bytes())?;
            f.sync_all()
        });
        if let Err(e) = written.and_then(|()| std::fs::rename(&tmp, &path)) {
            let _ = std::fs::remove_file(&tmp);
            return Err(io(e));
        }
        if let Ok(d) = File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(path)
    }
}

/// `metadata.yaml` could not be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot write the bag metadata {path}")]
pub struct BagMetadataWriteError {
    /// The file.
    pub path: PathBuf,
    /// What the OS said.
    pub source: std::io::Error,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(state: RecordingState) -> BagMetadata {
        let mut stats = RecordingStats::default();
        stats.messages.insert("/robot_description".into(), 1);
        stats.messages.insert("/joint_states".into(), 250);
        stats.log_time_span_ns = Some((1_700_000_000_000_000_000, 1_700_000_002_500_000_000));
        BagMetadata {
            file_name: "run.mcap".into(),
            topics: vec![
                BagTopic {
                    name: "/joint_states".into(),
                    type_name: "sensor_msgs/msg/JointState".into(),
                    qos: OfferedQos::for_topic("/joint_states"),
                },
                BagTopic {
                    name: "/robot_description".into(),
                    type_name: "std_msgs/msg/String".into(),
                    qos: OfferedQos::for_topic("/robot_description"),
                },
            ],
            stats,
            state,
        }
    }

    #[test]
    fn latched_topics_are_transient_local_and_the_rest_volatile() {
        assert_eq!(
            OfferedQos::for_topic("/robot_description"),
            OfferedQos::LATCHED
        );
        assert_eq!(OfferedQos::for_topic("/tf_static").depth, 1);
        assert_eq!(
            OfferedQos::for_topic("/tf").durability,
            Durability::Volatile
        );
        let ch = OfferedQos::LATCHED.channel_metadata();
        assert!(ch.starts_with("- history: keep_last\n  depth: 1\n"), "{ch}");
        assert!(ch.contains("\n  durability: transient_local\n"), "{ch}");
        assert!(
            ch.ends_with("\n  avoid_ros_namespace_conventions: false"),
            "{ch}"
        );
        assert!(
            OfferedQos::STREAMING
                .channel_metadata()
                .contains("durability: volatile")
        );
    }

    #[test]
    fn the_metadata_names_every_topic_with_its_count_qos_and_the_time_span() {
        let y = sample(RecordingState::Finished).to_yaml();
        for line in [
            "rosbag2_bagfile_information:",
            "  version: 9",
            "  storage_identifier: mcap",
            "  duration:\n    nanoseconds: 2500000000",
            "  starting_time:\n    nanoseconds_since_epoch: 1700000000000000000",
            "  message_count: 251",
            "        name: \"/robot_description\"\n        type: \"std_msgs/msg/String\"\n        serialization_format: cdr\n        offered_qos_profiles:\n          - history: keep_last\n            depth: 1\n            reliability: reliable\n            durability: transient_local\n",
            "            durability: volatile\n",
            "        type_description_hash: \"\"\n      message_count: 250",
            "        type_description_hash: \"\"\n      message_count: 1",
            "  relative_file_paths:\n    - \"run.mcap\"",
            "  files:\n    - path: \"run.mcap\"",
            "    foresight_recording: finished",
            "  ros_distro: jazzy",
        ] {
            assert!(y.contains(line), "missing {line:?} in\n{y}");
        }
        // Indentation: every line is a key, a list item, or a nested key; no tabs.
        assert!(!y.contains('\t'));
    }

    #[test]
    fn an_empty_recording_has_zero_span_and_an_empty_topic_list() {
        let md = BagMetadata {
            file_name: "run.mcap".into(),
            topics: Vec::new(),
            stats: RecordingStats::default(),
            state: RecordingState::Recording,
        };
        assert_eq!(md.time_span_ns(), (0, 0));
        let y = md.to_yaml();
        assert!(y.contains("  topics_with_message_count: []\n"), "{y}");
        assert!(y.contains("foresight_recording: recording"), "{y}");
    }

    #[test]
    fn strings_are_quoted_with_escapes() {
        assert_eq!(quoted("/a"), "\"/a\"");
        assert_eq!(quoted("a\"b\\c\n"), "\"a\\\"b\\\\c\\n\"");
        assert_eq!(quoted("\u{1}"), "\"\\x01\"");
    }

    #[test]
    fn the_file_is_replaced_whole_and_no_temporary_file_is_left() {
        let dir = std::env::temp_dir().join(format!("recorder-bag-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = sample(RecordingState::Recording);
        let path = first.write(&dir).unwrap();
        assert_eq!(path, dir.join(METADATA_FILE));
        assert_eq!(std::fs::read_to_string(&path).unwrap(), first.to_yaml());
        let last = sample(RecordingState::SizeLimit);
        last.write(&dir).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("foresight_recording: size_limit"));
        let names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, vec![METADATA_FILE.to_owned()]);
        // A folder that does not exist: an error naming the file, nothing created.
        let missing = dir.join("no/such/folder");
        let err = last.write(&missing).unwrap_err();
        assert_eq!(err.path, missing.join(METADATA_FILE));
        std::fs::remove_dir_all(&dir).ok();
    }
}
