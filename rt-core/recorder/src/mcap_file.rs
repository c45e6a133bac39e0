//! One MCAP file being written: ROS 2 channels (schema encoding `ros2msg`, message encoding
//! `cdr`, profile `ros2`, as `ros2 bag record -s mcap` writes them), bounded in size, written
//! in chunks so that a killed process leaves a file readable up to its last chunk.
//!
//! Chunks are built in memory and written whole (the writer never seeks back into the data
//! section), so the file on disk always ends at a record boundary: a reader without the
//! summary (the footer is written by [`McapFile::finish`]) reads every finished chunk.
//! [`McapFile::flush`] ends the chunk in progress; the recording thread calls it once a
//! second.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::bag::{BagMetadata, BagTopic, OfferedQos, RecordingState, RecordingStats};
use crate::cdr::CdrWriter;
use crate::msgs::RosMessage;

/// Size and chunking of a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct McapFileOptions {
    /// The file never grows past this (bytes, summary included); recording stops when the
    /// next message would not fit.
    pub max_bytes: u64,
    /// A chunk is closed and written once it holds this many bytes.
    pub chunk_bytes: u64,
}

/// Room kept for the summary section (schemas, channels, statistics, chunk indexes).
const SUMMARY_RESERVE_BYTES: u64 = 256 * 1024;

/// Why the file could not be created.
#[derive(Debug, thiserror::Error)]
pub enum McapCreateError {
    /// The folder or file could not be created.
    #[error("cannot create {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the OS said.
        source: std::io::Error,
    },
    /// The MCAP header could not be written.
    #[error("cannot start the MCAP file {path}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// What the mcap writer said.
        source: mcap::McapError,
    },
}

/// Why a message, a channel or the end of the file could not be written.
#[derive(Debug, thiserror::Error)]
pub enum McapWriteError {
    /// The topic was not added with [`McapFile::add_topic`].
    #[error("topic {0} was not added to the recording")]
    UnknownTopic(String),
    /// The mcap writer failed (disk full, I/O error); the file is readable up to its last
    /// finished chunk and nothing more is written.
    #[error("writing {path}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// What the mcap writer said.
        source: mcap::McapError,
    },
}

/// The file with a byte count of what reached it.
struct CountingFile {
    file: File,
    written: Arc<AtomicU64>,
}

impl Write for CountingFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.file.write(buf)?;
        self.written.fetch_add(n as u64, Ordering::Relaxed);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl Seek for CountingFile {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.file.seek(pos)
    }
}

enum State {
    Open(Box<mcap::Writer<CountingFile>>),
    /// Finished, full, or failed: nothing more is written.
    Closed,
}

/// An MCAP file of ROS 2 messages.
pub struct McapFile {
    state: State,
    path: PathBuf,
    opts: McapFileOptions,
    written: Arc<AtomicU64>,
    channels: HashMap<String, u16>,
    topics: Vec<BagTopic>,
    sequence: u32,
    last_log_time_ns: u64,
    cdr: CdrWriter,
    stats: RecordingStats,
}

impl std::fmt::Debug for McapFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapFile")
            .field("path", &self.path)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl McapFile {
    /// Creates `path` (and its folder). A file already there is never replaced or truncated
    /// (another recording, or a run's, may be writing it): that is an error.
    ///
    /// # Errors
    /// [`McapCreateError`]; [`McapCreateError::Io`] with [`std::io::ErrorKind::AlreadyExists`]
    /// when `path` exists.
    pub fn create(path: &Path, opts: McapFileOptions) -> Result<Self, McapCreateError> {
        let io = |source| McapCreateError::Io {
            path: path.to_path_buf(),
            source,
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(io)?;
        let written = Arc::new(AtomicU64::new(0));
        let sink = CountingFile {
            file,
            written: written.clone(),
        };
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library("foresight-recorder")
            .compression(None)
            .use_chunks(true)
            .chunk_size(Some(opts.chunk_bytes))
            // Chunks are built in memory and written whole: the file never holds half a chunk.
            .disable_seeking(true)
            .create(sink)
            .map_err(|source| McapCreateError::Mcap {
                path: path.to_path_buf(),
                source,
            })?;
        Ok(Self {
            state: State::Open(Box::new(writer)),
            path: path.to_path_buf(),
            opts,
            written,
            channels: HashMap::new(),
            topics: Vec::new(),
            sequence: 0,
            last_log_time_ns: 0,
            cdr: CdrWriter::new(),
            stats: RecordingStats::default(),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What was written so far.
    pub fn stats(&self) -> &RecordingStats {
        &self.stats
    }

    /// Whether messages are still being written (not full, failed or finished).
    pub fn is_open(&self) -> bool {
        matches!(self.state, State::Open(_))
    }

    fn fail(&mut self, source: mcap::McapError) -> McapWriteError {
        // Nothing more is written; dropping the writer tries to end the file cleanly.
        self.state = State::Closed;
        McapWriteError::Mcap {
            path: self.path.clone(),
            source,
        }
    }

    /// The topics added, in channel order.
    pub fn topics(&self) -> &[BagTopic] {
        &self.topics
    }

    /// What the bag's `metadata.yaml` says of this file now, in `state`.
    pub fn bag_metadata(&self, state: RecordingState) -> BagMetadata {
        BagMetadata {
            file_name: self
                .path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            topics: self.topics.clone(),
            stats: self.stats.clone(),
            state,
        }
    }

    /// Adds a channel for `topic` carrying `M` (its schema is written once per type), with
    /// the QoS profile its publisher offered in the channel metadata
    /// (`offered_qos_profiles`, the `ros2` MCAP profile).
    ///
    /// # Errors
    /// [`McapWriteError`].
    pub fn add_topic<M: RosMessage>(
        &mut self,
        topic: &str,
        qos: OfferedQos,
    ) -> Result<(), McapWriteError> {
        let State::Open(w) = &mut self.state else {
            return Ok(());
        };
        let metadata =
            BTreeMap::from([("offered_qos_profiles".to_owned(), qos.channel_metadata())]);
        let added = w
            .add_schema(M::TYPE_NAME, "ros2msg", M::definition().as_bytes())
            .and_then(|schema| w.add_channel(schema, topic, "cdr", &metadata));
        match added {
            Ok(id) => {
                self.channels.insert(topic.to_owned(), id);
                self.topics.push(BagTopic {
                    name: topic.to_owned(),
                    type_name: M::TYPE_NAME.to_owned(),
                    qos,
                });
                self.stats.messages.entry(topic.to_owned()).or_insert(0);
                Ok(())
            }
            Err(e) => Err(self.fail(e)),
        }
    }

    /// Writes `msg` on `topic` at `log_time_ns` (ns since the Unix epoch; a time before the
    /// previous message's is raised to it, so log time never goes back). Once the size
    /// limit is reached the file is finished, a warning says so once, and later messages
    /// are counted as dropped.
    ///
    /// # Errors
    /// [`McapWriteError`] (the file is closed after an I/O error).
    pub fn write<M: RosMessage>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        msg: &M,
    ) -> Result<(), McapWriteError> {
        if !self.is_open() {
            self.stats.dropped_at_limit += u64::from(self.stats.limit_reached);
            return Ok(());
        }
        let channel_id = *self
            .channels
            .get(topic)
            .ok_or_else(|| McapWriteError::UnknownTopic(topic.to_owned()))?;
        self.cdr.reset();
        msg.encode(&mut self.cdr);
        let len = self.cdr.as_bytes().len() as u64;
        let worst_case = self.written.load(Ordering::Relaxed) + self.opts.chunk_bytes + len + 64;
        if worst_case + SUMMARY_RESERVE_BYTES > self.opts.max_bytes {
            tracing::warn!(
                path = %self.path.display(),
                max_mib = self.opts.max_bytes / (1024 * 1024),
                "the recording reached its size limit; recording stopped (the file is complete up to here)"
            );
            self.stats.limit_reached = true;
            self.stats.dropped_at_limit += 1;
            return self.finish_in_place();
        }
        let log_time = log_time_ns.max(self.last_log_time_ns);
        self.last_log_time_ns = log_time;
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time,
            publish_time: log_time,
        };
        let State::Open(w) = &mut self.state else {
            return Ok(());
        };
        match w.write_to_known_channel(&header, self.cdr.as_bytes()) {
            Ok(()) => {
                *self.stats.messages.entry(topic.to_owned()).or_insert(0) += 1;
                let first = self.stats.log_time_span_ns.map_or(log_time, |(f, _)| f);
                self.stats.log_time_span_ns = Some((first, log_time));
                Ok(())
            }
            Err(e) => Err(self.fail(e)),
        }
    }

    /// Ends the chunk in progress and writes it, so a reader sees everything so far even if
    /// the process is killed next.
    ///
    /// # Errors
    /// [`McapWriteError`].
    pub fn flush(&mut self) -> Result<(), McapWriteError> {
        let State::Open(w) = &mut self.state else {
            return Ok(());
        };
        match w.flush() {
            Ok(()) => Ok(()),
            Err(e) => Err(self.fail(e)),
        }
    }

    fn finish_in_place(&mut self) -> Result<(), McapWriteError> {
        let State::Open(mut w) = std::mem::replace(&mut self.state, State::Closed) else {
            return Ok(());
        };
        let result = w.finish();
        self.stats.bytes = self.written.load(Ordering::Relaxed);
        let file = w.into_inner();
        let _ = file.file.sync_all();
        result.map(|_| ()).map_err(|source| McapWriteError::Mcap {
            path: self.path.clone(),
            source,
        })
    }

    /// Writes the last chunk, the summary and the footer, and closes the file.
    ///
    /// # Errors
    /// [`McapWriteError`].
    pub fn finish(mut self) -> Result<RecordingStats, McapWriteError> {
        self.finish_in_place()?;
        Ok(std::mem::take(&mut self.stats))
    }
}

impl Drop for McapFile {
    fn drop(&mut self) {
        let _ = self.finish_in_place();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::StringMsg;

    fn tmp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("recorder-test-{}", std::process::id()));
        dir.join(name)
    }

    #[test]
    fn a_finished_file_has_magic_at_both_ends() {
        let path = tmp("finished.mcap");
        let mut f = McapFile::create(
            &path,
            McapFileOptions {
                max_bytes: 1 << 20,
                chunk_bytes: 1024,
            },
        )
        .unwrap();
        f.add_topic::<StringMsg>("/t", OfferedQos::STREAMING)
            .unwrap();
        for i in 0..100 {
            let m = StringMsg {
                data: format!("message {i}"),
            };
            f.write("/t", 1_000 + i, &m).unwrap();
        }
        let stats = f.finish().unwrap();
        assert_eq!(stats.messages["/t"], 100);
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..8], b"\x89MCAP0\r\n");
        assert_eq!(&bytes[bytes.len() - 8..], b"\x89MCAP0\r\n");
        assert_eq!(stats.bytes, bytes.len() as u64);
    }

    /// Issue 41 item 5: `File::create` truncated a file already at the path (another
    /// run's recording, started in the same second); now the file is created new or not
    /// at all, and what was there stays whole.
    #[test]
    fn a_recording_never_truncates_a_file_already_there() {
        let path = tmp("taken.mcap");
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, b"another run's recording").unwrap();
        let opts = McapFileOptions {
            max_bytes: 1 << 20,
            chunk_bytes: 1024,
        };
        match McapFile::create(&path, opts) {
            Err(McapCreateError::Io { path: p, source }) => {
                assert_eq!(p, path);
                assert_eq!(source.kind(), std::io::ErrorKind::AlreadyExists);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(std::fs::read(&path).unwrap(), b"another run's recording");
        std::fs::remove_file(&path).ok();
    }

    #[test]
    fn the_file_stops_growing_at_its_limit_and_says_so() {
        let path = tmp("limited.mcap");
        let max_bytes = 300 * 1024;
        let mut f = McapFile::create(
            &path,
            McapFileOptions {
                max_bytes,
                chunk_bytes: 4096,
            },
        )
        .unwrap();
        f.add_topic::<StringMsg>("/t", OfferedQos::STREAMING)
            .unwrap();
        let m = StringMsg {
            data: "x".repeat(1000),
        };
        for i in 0..1000 {
            f.write("/t", i, &m).unwrap();
        }
        assert!(!f.is_open());
        let stats = f.finish().unwrap();
        assert!(stats.limit_reached);
        assert!(stats.dropped_at_limit > 0);
        assert_eq!(stats.total() + stats.dropped_at_limit, 1000);
        let len = std::fs::metadata(&path).unwrap().len();
        assert!(len <= max_bytes, "{len} > {max_bytes}");
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(
            &bytes[bytes.len() - 8..],
            b"\x89MCAP0\r\n",
            "finished cleanly"
        );
    }

    #[test]
    fn each_channel_carries_its_offered_qos_and_the_bag_metadata_its_topics() {
        let path = tmp("qos.mcap");
        let mut f = McapFile::create(
            &path,
            McapFileOptions {
                max_bytes: 1 << 20,
                chunk_bytes: 1024,
            },
        )
        .unwrap();
        f.add_topic::<StringMsg>("/robot_description", OfferedQos::LATCHED)
            .unwrap();
        f.add_topic::<StringMsg>("/t", OfferedQos::STREAMING)
            .unwrap();
        f.write("/robot_description", 2_000, &StringMsg::default())
            .unwrap();
        f.write("/t", 5_000, &StringMsg::default()).unwrap();
        f.write("/t", 9_000, &StringMsg::default()).unwrap();
        let md = f.bag_metadata(RecordingState::Finished);
        assert_eq!(md.file_name, "qos.mcap");
        assert_eq!(md.topics.len(), 2);
        assert_eq!(md.topics[0].type_name, "std_msgs/msg/String");
        assert_eq!(md.topics[1].qos, OfferedQos::STREAMING);
        assert_eq!(md.time_span_ns(), (2_000, 7_000));
        assert_eq!(md.message_count(), 3);
        let stats = f.finish().unwrap();
        assert_eq!(stats.log_time_span_ns, Some((2_000, 9_000)));
        let bytes = std::fs::read(&path).unwrap();
        let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
        let qos: BTreeMap<&str, &str> = summary
            .channels
            .values()
            .map(|c| {
                (
                    c.topic.as_str(),
                    c.metadata["offered_qos_profiles"].as_str(),
                )
            })
            .collect();
        assert_eq!(
            qos["/robot_description"],
            OfferedQos::LATCHED.channel_metadata()
        );
        assert_eq!(qos["/t"], OfferedQos::STREAMING.channel_metadata());
    }

    #[test]
    fn log_time_never_goes_back() {
        let path = tmp("monotonic.mcap");
        let mut f = McapFile::create(
            &path,
            McapFileOptions {
                max_bytes: 1 << 20,
                chunk_bytes: 1024,
            },
        )
        .unwrap();
        f.add_topic::<StringMsg>("/t", OfferedQos::STREAMING)
            .unwrap();
        f.write("/t", 500, &StringMsg::default()).unwrap();
        f.write("/t", 100, &StringMsg::default()).unwrap();
        assert_eq!(f.last_log_time_ns, 500);
        assert!(matches!(
            f.write("/nope", 600, &StringMsg::default()),
            Err(McapWriteError::UnknownTopic(t)) if t == "/nope"
        ));
    }
}
