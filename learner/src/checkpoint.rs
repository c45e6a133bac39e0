//! Training checkpoints: weights, Adam state, normalisation statistics, step count, random
//! streams and the task-config hash, in **one file** (torch's zip format through tch, so it is
//! also readable from Python with `torch.load`), written atomically: temporary file in the same
//! directory, `fsync`, `rename`, `fsync` of the directory. A crash at any point leaves either
//! the old or the new checkpoint, never a torn one.
//!
//! A run directory holds `last.ckpt` (after every evaluation) and `best.ckpt` (best evaluation
//! so far), plus `metrics.csv` and `reward.svg`.

use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use shm_schemas::ActionSpace;
use tch::Tensor;

use crate::env::Env;
use crate::net::{ActorCritic, NetFromFlatError, NetSpec};
use crate::normalize::RunningMeanStd;
use crate::ppo::{EvalResult, PpoConfig, Trainer};
use crate::random::RngState;

/// File format tag stored in every checkpoint.
pub const FORMAT: &str = "foresight-learner-ckpt-v1";
/// File name of the latest checkpoint in a run directory.
pub const LAST: &str = "last.ckpt";
/// File name of the best checkpoint in a run directory.
pub const BEST: &str = "best.ckpt";

/// Why a checkpoint could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// File system error.
    #[error("checkpoint I/O on {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// torch could not encode or decode the tensors.
    #[error("checkpoint tensors")]
    Tensor(#[from] tch::TchError),
    /// The checkpoint's network is not the trainer's.
    #[error("checkpoint network {checkpoint:?} does not match the trainer's {trainer:?}")]
    SpecMismatch {
        /// The checkpoint's.
        checkpoint: NetSpec,
        /// The trainer's.
        trainer: NetSpec,
    },
    /// A tensor is missing from the file.
    #[error("invalid checkpoint: missing tensor {0}")]
    MissingTensor(&'static str),
    /// The metadata could not be encoded or decoded.
    #[error("invalid checkpoint: metadata")]
    Meta(#[from] serde_json::Error),
    /// Another format version (the file's own text, hence a `String`).
    #[error("invalid checkpoint: format {found:?}, expected {FORMAT:?}")]
    Format {
        /// The file's format.
        found: String,
    },
    /// The weight or Adam tensors do not have the network's length.
    #[error(
        "invalid checkpoint: tensor lengths {theta}/{adam_m}/{adam_v} do not match the network's {expected}"
    )]
    Lengths {
        /// Weights.
        theta: usize,
        /// Adam's first moments.
        adam_m: usize,
        /// Adam's second moments.
        adam_v: usize,
        /// The network's parameter count.
        expected: usize,
    },
    /// The observation statistics do not have the network's input width.
    #[error("invalid checkpoint: observation statistics have the wrong length")]
    StatsLength,
    /// A weight is NaN or infinite.
    #[error("invalid checkpoint: non-finite weights")]
    NonFinite,
    /// The weights do not make a network of the stored shape.
    #[error("checkpoint weights")]
    Network(#[from] NetFromFlatError),
    /// The action space byte is one this build does not know, or its action length is not
    /// the network's.
    #[error(
        "invalid checkpoint: action space byte {byte} with a network of {act_dim} outputs (known: cartesian_step = 0 with 3, joint_step = 1 with 5)"
    )]
    ActionSpace {
        /// The stored byte.
        byte: u8,
        /// The network's action length.
        act_dim: usize,
    },
}

/// Running statistics as stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatsState {
    /// Mean.
    pub mean: Vec<f64>,
    /// Variance.
    pub var: Vec<f64>,
    /// Sample count.
    pub count: f64,
}

impl From<&RunningMeanStd> for StatsState {
    fn from(r: &RunningMeanStd) -> Self {
        Self {
            mean: r.mean.clone(),
            var: r.var.clone(),
            count: r.count,
        }
    }
}

impl StatsState {
    /// Back to running statistics.
    pub fn to_rms(&self) -> RunningMeanStd {
        RunningMeanStd {
            mean: self.mean.clone(),
            var: self.var.clone(),
            count: self.count,
        }
    }
}

/// Everything in a checkpoint except the three big vectors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckpointMeta {
    /// [`FORMAT`].
    pub format: String,
    /// Network shapes.
    pub spec: NetSpec,
    /// Hyper-parameters of the run.
    pub ppo: PpoConfig,
    /// Seed of the run.
    pub seed: u64,
    /// Hash of the task configuration the policy was trained for.
    pub task_hash: u64,
    /// Environment steps.
    pub steps: u64,
    /// Iterations.
    pub iteration: u64,
    /// Adam step count.
    pub adam_t: i64,
    /// Observation statistics.
    pub obs_rms: StatsState,
    /// Return statistics (reward scaling).
    pub ret_rms: StatsState,
    /// Trainer (shuffle) stream.
    pub trainer_rng: RngState,
    /// Per-environment streams.
    pub env_rngs: Vec<RngState>,
    /// Evaluation of these weights, if one was run.
    pub eval: Option<EvalResult>,
    /// Best evaluation of the run so far (the score `best.ckpt` holds).
    pub best_eval: Option<EvalResult>,
    /// The action space the policy acts in, as `PolicyBlob::action_space` stores it
    /// ([`ActionSpace`] byte: 0 the paper's Cartesian step, 1 the joint step). Absent from
    /// every checkpoint written before the joint step existed, and left out of Cartesian
    /// ones, so that their bytes are what they were.
    #[serde(default, skip_serializing_if = "is_cartesian")]
    pub action_space: u8,
}

fn is_cartesian(byte: &u8) -> bool {
    *byte == ActionSpace::CartesianStep as u8
}

impl CheckpointMeta {
    /// The action space the policy acts in (a checkpoint's byte is checked when it is
    /// read: [`CheckpointError::ActionSpace`]).
    pub fn action_space(&self) -> ActionSpace {
        ActionSpace::try_from(self.action_space).unwrap_or(ActionSpace::CartesianStep)
    }
}

/// A checkpoint in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint {
    /// Metadata.
    pub meta: CheckpointMeta,
    /// Network parameters (flat, see [`crate::net`]).
    pub theta: Vec<f32>,
    /// Adam first moment.
    pub adam_m: Vec<f32>,
    /// Adam second moment.
    pub adam_v: Vec<f32>,
}

fn to_vec(t: &Tensor) -> Vec<f32> {
    let t = t.detach().to_device(tch::Device::Cpu).contiguous();
    let n = t.numel();
    let mut v = vec![0.0f32; n];
    t.copy_data(&mut v, n);
    v
}

impl Checkpoint {
    /// Captures a trainer's full state.
    pub fn capture<E: Env + Clone>(t: &Trainer<E>, seed: u64, task_hash: u64) -> Self {
        Self {
            meta: CheckpointMeta {
                format: FORMAT.into(),
                spec: t.net.spec.clone(),
                ppo: t.cfg.clone(),
                seed,
                task_hash,
                steps: t.steps,
                iteration: t.iteration,
                adam_t: t.adam.t,
                obs_rms: (&t.obs_rms).into(),
                ret_rms: (&t.ret_rms).into(),
                trainer_rng: RngState::of(&t.rng),
                env_rngs: t.env_rng_states(),
                eval: None,
                best_eval: None,
                action_space: t.template().action_space() as u8,
            },
            theta: t.net.flat(),
            adam_m: to_vec(&t.adam.m),
            adam_v: to_vec(&t.adam.v),
        }
    }

    /// Restores a trainer (same network shape) to this state; episodes restart.
    ///
    /// # Errors
    /// [`CheckpointError::SpecMismatch`] when shapes do not match.
    pub fn restore<E: Env + Clone>(&self, t: &mut Trainer<E>) -> Result<(), CheckpointError> {
        if self.meta.spec != t.net.spec {
            return Err(CheckpointError::SpecMismatch {
                checkpoint: self.meta.spec.clone(),
                trainer: t.net.spec.clone(),
            });
        }
        let dev = t.net.device();
        t.net = ActorCritic::from_flat(self.meta.spec.clone(), &self.theta, dev)?;
        t.adam.m = Tensor::from_slice(&self.adam_m).to_device(dev);
        t.adam.v = Tensor::from_slice(&self.adam_v).to_device(dev);
        t.adam.t = self.meta.adam_t;
        t.obs_rms = self.meta.obs_rms.to_rms();
        t.ret_rms = self.meta.ret_rms.to_rms();
        t.steps = self.meta.steps;
        t.iteration = self.meta.iteration;
        t.rng = self.meta.trainer_rng.restore();
        t.restore_env_rngs(&self.meta.env_rngs);
        Ok(())
    }

    /// The network these weights describe.
    ///
    /// # Errors
    /// [`CheckpointError::Network`] on a length mismatch.
    pub fn network(&self, device: tch::Device) -> Result<ActorCritic, CheckpointError> {
        Ok(ActorCritic::from_flat(
            self.meta.spec.clone(),
            &self.theta,
            device,
        )?)
    }

    /// Encodes to bytes (torch zip format).
    ///
    /// # Errors
    /// [`CheckpointError::Tensor`] if torch fails.
    pub fn to_bytes(&self) -> Result<Vec<u8>, CheckpointError> {
        let meta = serde_json::to_vec(&self.meta)?;
        let named = [
            ("meta", Tensor::from_slice(&meta)),
            ("theta", Tensor::from_slice(&self.theta)),
            ("adam_m", Tensor::from_slice(&self.adam_m)),
            ("adam_v", Tensor::from_slice(&self.adam_v)),
        ];
        let mut out = Cursor::new(Vec::new());
        Tensor::save_multi_to_stream(&named, &mut out)?;
        Ok(out.into_inner())
    }

    /// Decodes and checks bytes written by [`Checkpoint::to_bytes`].
    ///
    /// # Errors
    /// [`CheckpointError`] for undecodable or inconsistent content.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, CheckpointError> {
        let named = Tensor::load_multi_from_stream(Cursor::new(bytes))?;
        let get = |name: &'static str| {
            named
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, t)| t.shallow_clone())
                .ok_or(CheckpointError::MissingTensor(name))
        };
        let meta_t = get("meta")?;
        let n = meta_t.numel();
        let mut meta = vec![0u8; n];
        meta_t.copy_data(&mut meta, n);
        let meta: CheckpointMeta = serde_json::from_slice(&meta)?;
        if meta.format != FORMAT {
            return Err(CheckpointError::Format { found: meta.format });
        }
        let ck = Self {
            theta: to_vec(&get("theta")?),
            adam_m: to_vec(&get("adam_m")?),
            adam_v: to_vec(&get("adam_v")?),
            meta,
        };
        let len = ck.meta.spec.layout().len;
        if ck.theta.len() != len || ck.adam_m.len() != len || ck.adam_v.len() != len {
            return Err(CheckpointError::Lengths {
                theta: ck.theta.len(),
                adam_m: ck.adam_m.len(),
                adam_v: ck.adam_v.len(),
                expected: len,
            });
        }
        if ck.meta.obs_rms.mean.len() != ck.meta.spec.obs_dim {
            return Err(CheckpointError::StatsLength);
        }
        // A Cartesian byte is what every older checkpoint reads as, whatever its network
        // (toy tasks have other action lengths); a joint-step one must have five outputs.
        match ActionSpace::try_from(ck.meta.action_space) {
            Ok(ActionSpace::CartesianStep) => {}
            Ok(space) if space.act_dim() == ck.meta.spec.act_dim => {}
            _ => {
                return Err(CheckpointError::ActionSpace {
                    byte: ck.meta.action_space,
                    act_dim: ck.meta.spec.act_dim,
                });
            }
        }
        if ck.theta.iter().any(|x| !x.is_finite()) {
            return Err(CheckpointError::NonFinite);
        }
        Ok(ck)
    }

    /// Writes atomically to `path`.
    ///
    /// # Errors
    /// [`CheckpointError`]; on error the previous file at `path` is untouched.
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        write_atomic(path, &self.to_bytes()?)
    }

    /// Reads `path`; a directory means its `best.ckpt` (or `last.ckpt` if there is no best).
    ///
    /// # Errors
    /// [`CheckpointError`].
    pub fn load(path: &Path) -> Result<Self, CheckpointError> {
        let file = resolve(path);
        let bytes = std::fs::read(&file).map_err(|source| CheckpointError::Io {
            path: file.clone(),
            source,
        })?;
        Self::from_bytes(&bytes)
    }
}

/// `path` itself if it is a file; for a directory its `best.ckpt` if present, else `last.ckpt`.
pub fn resolve(path: &Path) -> PathBuf {
    if path.is_dir() {
        let best = path.join(BEST);
        if best.exists() { best } else { path.join(LAST) }
    } else {
        path.to_path_buf()
    }
}

/// Writes `data` to `path` atomically (temp file beside it, fsync, rename, fsync directory).
///
/// # Errors
/// [`CheckpointError::Io`]; the old file is untouched on error.
pub fn write_atomic(path: &Path, data: &[u8]) -> Result<(), CheckpointError> {
    write_atomic_inner(path, data, None)
}

/// As [`write_atomic`], with an injected crash after `crash_after` bytes (for tests): the
/// function returns an error at that point, as if the process had died before the rename.
#[doc(hidden)]
pub fn write_atomic_inner(
    path: &Path,
    data: &[u8],
    crash_after: Option<usize>,
) -> Result<(), CheckpointError> {
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |source| CheckpointError::Io { path: p, source }
    };
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp.{}", std::process::id()));
    {
        let mut f = std::fs::File::create(&tmp).map_err(io(&tmp))?;
        if let Some(n) = crash_after {
            f.write_all(&data[..n.min(data.len())]).map_err(io(&tmp))?;
            return Err(CheckpointError::Io {
                path: tmp,
                source: std::io::Error::other("simulated crash"),
            });
        }
        f.write_all(data).map_err(io(&tmp))?;
        f.sync_all().map_err(io(&tmp))?;
    }
    std::fs::rename(&tmp, path).map_err(io(path))?;
    if let Ok(d) = std::fs::File::open(dir) {
        // Persist the rename; not all file systems support fsync on directories.
        let _ = d.sync_all();
    }
    Ok(())
}
