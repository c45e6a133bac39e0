//! Service names, the [`ShmMessage`] trait that binds each payload to its service, schema
//! version and queue settings, and the helpers every process uses to open ports the same
//! way: [`open_publisher`], [`open_subscriber`], [`create_node`].
//!
//! Each service carries the attribute `foresight.schema_version = <N>`; the helpers create
//! the service with it or, when it exists, *require* it, so a process built against another
//! schema refuses to connect ([`ShmOpenError::SchemaMismatch`]) instead of misreading
//! memory. The payload's type name (`foresight::<Name>.v<N>`) is checked by iceoryx2 too.
//!
//! ```no_run
//! use iceoryx2::prelude::*;
//! use shm_schemas::{DetectionFrame, services};
//! let (node, _cleanup) = services::create_node::<ipc::Service>("perception").unwrap();
//! let publisher = services::open_publisher::<DetectionFrame, _>(&node, "run42").unwrap();
//! let subscriber = services::open_subscriber::<DetectionFrame, _>(&node, "run42").unwrap();
//! # let _ = (publisher, subscriber);
//! ```

use core::fmt::Debug;

use iceoryx2::config::ConfigCreationError;
use iceoryx2::node::{CleanupState, Node, NodeBuilder, NodeCreationFailure};
use iceoryx2::port::LoanError;
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::subscriber::{Subscriber, SubscriberCreateError};
use iceoryx2::prelude::{
    AttributeVerifier, Config, FilePath, NodeName, SemanticString, ServiceName, ZeroCopySend,
};
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::service::Service;
use iceoryx2::service::attribute::{AttributeKey, AttributeValue};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeCreateError, PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};

use crate::error::SchemaError;
use crate::{
    DetectionFrame, GoalRefusal, GoalRequest, PolicyBlob, RetrainProgress, RetrainRequest,
    RobotState, TwinVerdict,
};

/// Detections, perception → rt-core ([`DetectionFrame`]).
pub const DETECTIONS: &str = "foresight/detections";
/// Policies, learner → rt-core ([`PolicyBlob`]).
pub const POLICIES: &str = "foresight/policies";
/// Retrain requests, rt-core → learner ([`RetrainRequest`]).
pub const RETRAIN_REQUESTS: &str = "foresight/retrain_requests";
/// Retrain progress, learner → anyone ([`RetrainProgress`]).
pub const RETRAIN_PROGRESS: &str = "foresight/retrain_progress";
/// Robot state and cycle statistics, rt-core → anyone ([`RobotState`]).
pub const ROBOT_STATE: &str = "foresight/robot_state";
/// Lookahead verdicts, rt-core → anyone ([`TwinVerdict`]).
pub const TWIN_VERDICTS: &str = "foresight/twin_verdicts";
/// Goal requests (the ROS 2 `Reach` action), ros-bridge → rt-core ([`GoalRequest`]).
pub const GOAL_REQUESTS: &str = "foresight/goal_requests";
/// Goal requests rt-core refused (by age, bounds, id), rt-core → ros-bridge
/// ([`GoalRefusal`]): the action goal behind one ends at once.
pub const GOAL_REFUSALS: &str = "foresight/goal_refusals";

/// The attribute key that carries the schema version.
pub const SCHEMA_VERSION_KEY: &str = "foresight.schema_version";

/// The full service name: `<prefix>/<base>`, or `base` when `prefix` is empty. The
/// launcher gives every run a unique prefix so parallel runs and tests never meet.
pub fn service_name(prefix: &str, base: &str) -> String {
    let prefix = prefix.trim_end_matches('/');
    if prefix.is_empty() {
        base.to_owned()
    } else {
        format!("{prefix}/{base}")
    }
}

/// Queue settings of a service. Every opener uses the same values (iceoryx2 refuses to
/// open a service with fewer resources than requested).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueueSettings {
    /// Samples a late subscriber receives on connect.
    pub history_size: usize,
    /// Samples a subscriber can hold unread (the oldest is overwritten when full).
    pub subscriber_buffer: usize,
    /// Most publishers.
    pub max_publishers: usize,
    /// Most subscribers.
    pub max_subscribers: usize,
}

/// A payload type bound to its service: name, schema version, queue settings, validation.
///
/// # Safety
/// Implementors guarantee that every bit pattern, the all-zero one included, is a valid
/// value of the type (every field an integer, a float or an array/struct of them — no
/// `bool`, no Rust enum, no reference) and that the type has no padding bytes (each type's
/// size is asserted against the sum of its fields). [`loan_zeroed`] relies on the first,
/// [`message_bytes`] and [`message_from_bytes`] on both.
pub unsafe trait ShmMessage: Debug + ZeroCopySend + Sized + 'static {
    /// Base service name (one of the constants of this module).
    const SERVICE: &'static str;
    /// Schema version, carried as the `foresight.schema_version` attribute.
    const SCHEMA_VERSION: u32;
    /// Queue settings.
    const QUEUE: QueueSettings;
    /// The type's `validate()`.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    fn validate_message(&self) -> Result<(), SchemaError>;
}

const LATEST: QueueSettings = QueueSettings {
    history_size: 1,
    subscriber_buffer: 4,
    max_publishers: 2,
    max_subscribers: 8,
};

const EVENTS: QueueSettings = QueueSettings {
    history_size: 1,
    subscriber_buffer: 16,
    max_publishers: 2,
    max_subscribers: 8,
};

macro_rules! message {
    ($ty:ty, $service:expr, $queue:expr) => {
        // SAFETY: every payload of this crate consists only of integers, floats and arrays
        // or `repr(C)` structs of them (flags and enums are stored as `u8`), so all-zero is valid.
        unsafe impl ShmMessage for $ty {
            const SERVICE: &'static str = $service;
            const SCHEMA_VERSION: u32 = <$ty>::SCHEMA_VERSION;
            const QUEUE: QueueSettings = $queue;
            fn validate_message(&self) -> Result<(), SchemaError> {
                self.validate()
            }
        }
    };
}

message!(DetectionFrame, DETECTIONS, LATEST);
message!(
    PolicyBlob,
    POLICIES,
    QueueSettings {
        history_size: 1,
        subscriber_buffer: 2,
        max_publishers: 2,
        max_subscribers: 4,
    }
);
message!(RetrainRequest, RETRAIN_REQUESTS, EVENTS);
message!(RetrainProgress, RETRAIN_PROGRESS, EVENTS);
message!(RobotState, ROBOT_STATE, LATEST);
message!(TwinVerdict, TWIN_VERDICTS, EVENTS);
message!(GoalRequest, GOAL_REQUESTS, EVENTS);
message!(GoalRefusal, GOAL_REFUSALS, EVENTS);

/// Why a port could not be opened.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ShmOpenError {
    /// The prefixed service name is not a valid iceoryx2 service name.
    #[error("invalid service name for `{0}` (prefix too long or malformed)")]
    InvalidName(&'static str),
    /// The service exists with another schema version or payload type: a process of a
    /// different build created it. Refusing to connect.
    #[error(
        "service `{0}` exists with a different schema version or payload type; refusing to connect"
    )]
    SchemaMismatch(&'static str),
    /// The service could not be opened or created for another reason.
    #[error("cannot open or create service `{service}`: {error:?}")]
    Service {
        /// Base service name.
        service: &'static str,
        /// What iceoryx2 said.
        error: PublishSubscribeOpenOrCreateError,
    },
    /// The publisher port could not be created.
    #[error("cannot create a publisher on `{service}`: {error:?}")]
    Publisher {
        /// Base service name.
        service: &'static str,
        /// What iceoryx2 said.
        error: PublisherCreateError,
    },
    /// The subscriber port could not be created.
    #[error("cannot create a subscriber on `{service}`: {error:?}")]
    Subscriber {
        /// Base service name.
        service: &'static str,
        /// What iceoryx2 said.
        error: SubscriberCreateError,
    },
}

/// The attribute verifier every opener uses: requires `foresight.schema_version = version`
/// (and defines it when the service is created).
///
/// # Errors
/// [`ShmOpenError::InvalidName`] if iceoryx2 refuses the attribute (cannot happen for the
/// fixed key and a decimal value).
pub fn schema_verifier(
    service: &'static str,
    version: u32,
) -> Result<AttributeVerifier, ShmOpenError> {
    let key = AttributeKey::try_from(SCHEMA_VERSION_KEY)
        .map_err(|_| ShmOpenError::InvalidName(service))?;
    let value = AttributeValue::try_from(version.to_string().as_str())
        .map_err(|_| ShmOpenError::InvalidName(service))?;
    AttributeVerifier::new()
        .require(&key, &value)
        .map_err(|_| ShmOpenError::InvalidName(service))
}

/// Opens (or creates) the service of `T` under `prefix` with the schema attribute
/// required and the type's queue settings.
///
/// # Errors
/// [`ShmOpenError`].
pub fn open_service<T: ShmMessage, S: Service>(
    node: &Node<S>,
    prefix: &str,
) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, T, ()>, ShmOpenError>
{
    open_service_with_version::<T, S>(node, prefix, T::SCHEMA_VERSION)
}

/// As [`open_service`] with an explicit schema version (for tests of the refusal path).
///
/// # Errors
/// [`ShmOpenError`].
pub fn open_service_with_version<T: ShmMessage, S: Service>(
    node: &Node<S>,
    prefix: &str,
    version: u32,
) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, T, ()>, ShmOpenError>
{
    let full = service_name(prefix, T::SERVICE);
    let name = ServiceName::new(&full).map_err(|_| ShmOpenError::InvalidName(T::SERVICE))?;
    let verifier = schema_verifier(T::SERVICE, version)?;
    let q = T::QUEUE;
    let deadline = std::time::Instant::now() + OPEN_RETRY_WINDOW;
    loop {
        let attempt = node
            .service_builder(&name)
            .publish_subscribe::<T>()
            .history_size(q.history_size)
            .subscriber_max_buffer_size(q.subscriber_buffer)
            .max_publishers(q.max_publishers)
            .max_subscribers(q.max_subscribers)
            .enable_safe_overflow(true)
            .open_or_create_with_attributes(&verifier);
        match attempt {
            Ok(factory) => return Ok(factory),
            Err(PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                PublishSubscribeOpenError::IncompatibleAttributes
                | PublishSubscribeOpenError::IncompatibleTypes,
            )) => return Err(ShmOpenError::SchemaMismatch(T::SERVICE)),
            Err(error) if is_transient(error) && std::time::Instant::now() < deadline => {
                std::thread::sleep(OPEN_RETRY_PAUSE);
            }
            Err(error) => {
                return Err(ShmOpenError::Service {
                    service: T::SERVICE,
                    error,
                });
            }
        }
    }
}

/// How long [`open_service`] keeps retrying a service that another process is creating or
/// removing at the same moment. The launcher starts four processes that open the same
/// services together; on a loaded two-core machine one of them can be descheduled in the
/// middle of a creation for longer than iceoryx2's creation timeout, and the others then see
/// `HangsInCreation`, or `DoesNotExist` after a create/open ping-pong (seen in CI). A
/// service that is still in that state after this window is reported.
pub const OPEN_RETRY_WINDOW: std::time::Duration = std::time::Duration::from_secs(15);
const OPEN_RETRY_PAUSE: std::time::Duration = std::time::Duration::from_millis(50);

/// The least creation timeout [`create_node`] gives iceoryx2 (its default is 500 ms): how
/// long an opener waits for a creation in progress before it calls the service hung.
pub const MIN_CREATION_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(2);

/// Errors that mean "another process is creating or removing this service right now".
fn is_transient(error: PublishSubscribeOpenOrCreateError) -> bool {
    use PublishSubscribeCreateError as C;
    use PublishSubscribeOpenError as O;
    matches!(
        error,
        PublishSubscribeOpenOrCreateError::SystemInFlux
            | PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                O::DoesNotExist | O::HangsInCreation | O::IsMarkedForDestruction
            )
            | PublishSubscribeOpenOrCreateError::PublishSubscribeCreateError(
                C::AlreadyExists | C::IsBeingCreatedByAnotherInstance | C::HangsInCreation
            )
    )
}

/// A publisher of `T` on `<prefix>/<T::SERVICE>` (see [`open_service`]).
///
/// # Errors
/// [`ShmOpenError`].
pub fn open_publisher<T: ShmMessage, S: Service>(
    node: &Node<S>,
    prefix: &str,
) -> Result<Publisher<S, T, ()>, ShmOpenError> {
    open_service::<T, S>(node, prefix)?
        .publisher_builder()
        .create()
        .map_err(|error| ShmOpenError::Publisher {
            service: T::SERVICE,
            error,
        })
}

/// A subscriber of `T` on `<prefix>/<T::SERVICE>` (see [`open_service`]).
///
/// # Errors
/// [`ShmOpenError`].
pub fn open_subscriber<T: ShmMessage, S: Service>(
    node: &Node<S>,
    prefix: &str,
) -> Result<Subscriber<S, T, ()>, ShmOpenError> {
    open_service::<T, S>(node, prefix)?
        .subscriber_builder()
        .create()
        .map_err(|error| ShmOpenError::Subscriber {
            service: T::SERVICE,
            error,
        })
}

/// Loans a sample whose payload is zeroed in place in shared memory, ready to be filled
/// field by field — the way to publish a large payload ([`PolicyBlob`], ~320 KB) without a
/// stack copy:
///
/// ```no_run
/// # use iceoryx2::prelude::*;
/// # use shm_schemas::{PolicyBlob, PolicyBlobBuilder, services};
/// # let (node, _) = services::create_node::<ipc::Service>("learner").unwrap();
/// let publisher = services::open_publisher::<PolicyBlob, _>(&node, "run42").unwrap();
/// let builder = PolicyBlobBuilder::random(1, 0xabc, 17, &[256, 256], 3, 7);
/// let mut sample = services::loan_zeroed(&publisher).unwrap();
/// builder.write_into(sample.payload_mut()).unwrap();
/// sample.send().unwrap();
/// ```
///
/// # Errors
/// iceoryx2's [`LoanError`] (e.g. all samples loaned out).
pub fn loan_zeroed<T: ShmMessage, S: Service>(
    publisher: &Publisher<S, T, ()>,
) -> Result<SampleMut<S, T, ()>, LoanError> {
    let mut sample = publisher.loan_uninit()?;
    // SAFETY: `write_bytes` initialises every byte of the payload, and `ShmMessage`
    // guarantees the all-zero pattern is a valid `T`.
    unsafe {
        core::ptr::write_bytes(sample.payload_mut().as_mut_ptr(), 0, 1);
        Ok(sample.assume_init())
    }
}

/// The bytes of a message, native-endian, exactly `size_of::<T>()` of them: what the
/// host-to-host relay puts on the wire (with a header naming the service and schema version).
pub fn message_bytes<T: ShmMessage>(message: &T) -> &[u8] {
    // SAFETY: `ShmMessage` guarantees `T` has no padding, so all `size_of::<T>()` bytes of a
    // live `T` are initialised; the slice borrows `message` for its lifetime.
    unsafe { core::slice::from_raw_parts((message as *const T).cast::<u8>(), size_of::<T>()) }
}

/// Why bytes from outside the process are not a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MessageBytesError {
    /// The byte count is not the type's size.
    #[error("{service}: {got} bytes where the payload has {expected}")]
    Length {
        /// Base service name of the type.
        service: &'static str,
        /// Bytes received.
        got: usize,
        /// `size_of` the type.
        expected: usize,
    },
    /// The bytes are a well-formed value that fails the type's validation.
    #[error("{service}: {error}")]
    Invalid {
        /// Base service name of the type.
        service: &'static str,
        /// The first field found wrong.
        error: SchemaError,
    },
}

/// A message read from untrusted bytes (e.g. from the network): the length must be the
/// type's size and the value must pass its `validate()`. The value is built on the heap
/// (a [`PolicyBlob`] is ~320 KB) without a stack copy.
///
/// # Errors
/// [`MessageBytesError`] naming the service and the field.
pub fn message_from_bytes<T: ShmMessage>(bytes: &[u8]) -> Result<Box<T>, MessageBytesError> {
    if bytes.len() != size_of::<T>() {
        return Err(MessageBytesError::Length {
            service: T::SERVICE,
            got: bytes.len(),
            expected: size_of::<T>(),
        });
    }
    let mut slot = Box::<T>::new_uninit();
    // SAFETY: the destination is a fresh allocation of exactly `size_of::<T>()` bytes, the
    // source has that many bytes (checked above) and they do not overlap; `ShmMessage`
    // guarantees every bit pattern is a valid `T`, so the fully written slot is initialised.
    let message = unsafe {
        core::ptr::copy_nonoverlapping(bytes.as_ptr(), slot.as_mut_ptr().cast::<u8>(), bytes.len());
        slot.assume_init()
    };
    message
        .validate_message()
        .map_err(|error| MessageBytesError::Invalid {
            service: T::SERVICE,
            error,
        })?;
    Ok(message)
}

/// Why a node could not be created.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum NodeCreateError {
    /// The name is not a valid node name.
    #[error("invalid node name")]
    InvalidName,
    /// iceoryx2 could not create the node.
    #[error("cannot create the iceoryx2 node: {0:?}")]
    Create(NodeCreationFailure),
    /// The iceoryx2 configuration file (`$FORESIGHT_ICEORYX2_CONFIG`, else
    /// `assets/iceoryx2.toml`) exists but cannot be loaded.
    #[error(
        "cannot load the iceoryx2 configuration (${ICEORYX2_CONFIG_ENV}, else {ICEORYX2_CONFIG_FILE}): {0:?}"
    )]
    Config(ConfigCreationError),
}

/// The environment variable that names the iceoryx2 configuration file of a Foresight
/// process (a deployment's own); see [`global_config`].
pub const ICEORYX2_CONFIG_ENV: &str = "FORESIGHT_ICEORYX2_CONFIG";

/// The iceoryx2 configuration Foresight ships, relative to the folder a process starts in
/// (the repository root, where `make demo` and the launcher run).
pub const ICEORYX2_CONFIG_FILE: &str = "assets/iceoryx2.toml";

/// iceoryx2's global configuration of this process, set up on first use: the file
/// `$FORESIGHT_ICEORYX2_CONFIG` names, else [`ICEORYX2_CONFIG_FILE`] when it is there, else
/// iceoryx2's own lookup (`config/iceoryx2.toml`, the user's, `/etc/iceoryx2/`), which
/// prints a warning when it finds no file. Loading a named file prints nothing, so a
/// normal run's console stays clean.
///
/// # Errors
/// [`NodeCreateError::Config`] when the file is there but unreadable or malformed.
pub fn global_config() -> Result<&'static Config, NodeCreateError> {
    // Once per process, whichever thread comes first: iceoryx2 warns when two threads set
    // up its global configuration at the same moment.
    static LOADED: std::sync::OnceLock<Result<&'static Config, NodeCreateError>> =
        std::sync::OnceLock::new();
    *LOADED.get_or_init(load_global_config)
}

/// The installed assets folder a process was given (`--assets`), set once at start-up
/// ([`set_assets_dir`]).
static ASSETS_DIR: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();

/// Names the folder of the installed assets (a process's `--assets`): its `iceoryx2.toml` is
/// used before the current folder's [`ICEORYX2_CONFIG_FILE`], so a process started from
/// anywhere (a service manager, a test harness) finds the shipped configuration. Call it
/// before the first node; returns `false` when a folder was set already (the first stays).
pub fn set_assets_dir(dir: &std::path::Path) -> bool {
    ASSETS_DIR.set(dir.to_path_buf()).is_ok()
}

/// Which iceoryx2 configuration file to load: `env_value` (`$FORESIGHT_ICEORYX2_CONFIG`) when
/// set, else `<assets_dir>/iceoryx2.toml` when it is there, else [`ICEORYX2_CONFIG_FILE`]
/// under the current folder when it is there, else none (iceoryx2's own lookup).
fn config_file_to_load(
    env_value: Option<String>,
    assets_dir: Option<&std::path::Path>,
) -> Option<String> {
    env_value.filter(|p| !p.is_empty()).or_else(|| {
        assets_dir
            .map(|d| d.join("iceoryx2.toml"))
            .filter(|p| p.is_file())
            .map(|p| p.to_string_lossy().into_owned())
            .or_else(|| {
                std::path::Path::new(ICEORYX2_CONFIG_FILE)
                    .is_file()
                    .then(|| ICEORYX2_CONFIG_FILE.to_owned())
            })
    })
}

fn load_global_config() -> Result<&'static Config, NodeCreateError> {
    let file = config_file_to_load(
        std::env::var(ICEORYX2_CONFIG_ENV).ok(),
        ASSETS_DIR.get().map(std::path::PathBuf::as_path),
    );
    match file {
        Some(path) => {
            let path = FilePath::new(path.as_bytes()).map_err(|_| {
                NodeCreateError::Config(ConfigCreationError::FailedToReadConfigFileContents)
            })?;
            Config::setup_global_config_from_file(&path).map_err(NodeCreateError::Config)
        }
        None => Ok(Config::global_config()),
    }
}

/// Creates a named node and then removes the stale resources (shared memory, service
/// registrations) of every dead node — a crashed earlier run must never stop a restart.
/// Returns the node and how many dead nodes were cleaned (and how many could not be).
///
/// # Errors
/// [`NodeCreateError`].
///
/// iceoryx2's default configuration also cleans dead nodes on node creation and service
/// open; this explicit pass keeps the guarantee when a deployment's config turns those off.
///
/// The node uses the process's iceoryx2 configuration ([`global_config`]: Foresight's
/// `assets/iceoryx2.toml`, a deployment's file, or the defaults) with the creation timeout
/// raised to at least [`MIN_CREATION_TIMEOUT`].
pub fn create_node<S: Service>(name: &str) -> Result<(Node<S>, CleanupState), NodeCreateError> {
    let mut config = global_config()?.clone();
    config.global.creation_timeout = config.global.creation_timeout.max(MIN_CREATION_TIMEOUT);
    create_node_with_config(name, &config)
}

/// As [`create_node`] with an explicit iceoryx2 configuration.
///
/// # Errors
/// [`NodeCreateError`].
pub fn create_node_with_config<S: Service>(
    name: &str,
    config: &Config,
) -> Result<(Node<S>, CleanupState), NodeCreateError> {
    let name = NodeName::new(name).map_err(|_| NodeCreateError::InvalidName)?;
    let node = NodeBuilder::new()
        .name(&name)
        .config(config)
        .create::<S>()
        .map_err(NodeCreateError::Create)?;
    let cleanup = node.try_cleanup_dead_nodes();
    Ok((node, cleanup))
}

#[cfg(test)]
mod config_tests {
    use super::*;

    /// Issue 30 item 7: the shipped configuration is found from the installed assets, not
    /// only from a process started in the repository root.
    #[test]
    fn the_iceoryx2_config_is_found_in_the_assets_folder_before_the_current_folder() {
        let assets = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets"));
        let chosen = config_file_to_load(None, Some(assets)).unwrap();
        assert!(chosen.ends_with("assets/iceoryx2.toml"), "{chosen}");
        assert!(std::path::Path::new(&chosen).is_absolute(), "{chosen}");
        // The environment's file wins; an empty value does not count.
        assert_eq!(
            config_file_to_load(Some("/etc/x.toml".into()), Some(assets)).as_deref(),
            Some("/etc/x.toml")
        );
        assert_eq!(
            config_file_to_load(Some(String::new()), Some(assets)),
            Some(chosen)
        );
        // A folder without the file falls back to the current folder's, if any.
        let empty = std::env::temp_dir();
        let fallback = config_file_to_load(None, Some(&empty));
        assert_eq!(
            fallback.is_some(),
            std::path::Path::new(ICEORYX2_CONFIG_FILE).is_file()
        );
    }

    /// The shipped `assets/iceoryx2.toml` loads, and says what iceoryx2's defaults say
    /// except the creation timeout: every process, with the file or without, agrees.
    #[test]
    fn the_shipped_iceoryx2_config_loads_and_keeps_the_defaults() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/iceoryx2.toml");
        let shipped = Config::from_file(&FilePath::new(path.as_bytes()).unwrap()).unwrap();
        let mut expected = Config::default();
        expected.global.creation_timeout = MIN_CREATION_TIMEOUT;
        assert_eq!(shipped, expected);
    }
}
