//! Export of a checkpoint's actor to the [`PolicyBlob`] layout that rt-core runs without
//! allocation, and the blob file format.
//!
//! The blob holds the actor MLP only (tanh hidden layers, identity output), the observation
//! normalisation (`std = sqrt(var + 1e-8)`, clip as in training) and `action_clip = 1`,
//! `action_scale = 1`: the twin takes actions in `[-1, 1]` and applies `action.scale_m`
//! itself, so the blob's output is exactly what training fed the twin (the clipped mean).
//!
//! # File format
//! A `.blob` file is the blob's `repr(C)` bytes in the machine's (little-endian) byte order,
//! `size_of::<PolicyBlob>()` bytes, as it sits in shared memory; readers validate it.

use std::path::{Path, PathBuf};

use shm_schemas::checksum::Fnv1a64;
use shm_schemas::{Activation, PolicyBlob, PolicyBlobBuilder, PolicyBuildError, SchemaError};

use crate::checkpoint::{Checkpoint, CheckpointError, write_atomic};
use crate::normalize::ObsNormalizer;

/// Why a blob could not be made, written or read.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The builder rejected the network.
    #[error("policy blob")]
    Build(#[from] PolicyBuildError),
    /// Writing failed.
    #[error(transparent)]
    Write(#[from] CheckpointError),
    /// Reading failed.
    #[error("cannot read {}", .path.display())]
    Read {
        /// File.
        path: PathBuf,
        /// OS error.
        source: std::io::Error,
    },
    /// The file is not a valid blob (wrong length, or a field fails validation).
    #[error("invalid policy blob file")]
    Invalid(#[source] SchemaError),
}

/// A policy id for a checkpoint (what `learner export` and `learner serve` give it): FNV-1a
/// of its weights, step count and task hash, never 0.
pub fn policy_id_for(ck: &Checkpoint) -> u64 {
    let mut h = Fnv1a64::new();
    h.write_f32s(&ck.theta);
    h.write_u64(ck.meta.steps);
    h.write_u64(ck.meta.task_hash);
    h.finish().max(1)
}

/// A builder holding the checkpoint's actor and normalisation, and its action space (the
/// blob records the space's observation layout with it).
pub fn builder(ck: &Checkpoint, policy_id: u64) -> PolicyBlobBuilder {
    let spec = &ck.meta.spec;
    let layout = spec.layout();
    let mut b = PolicyBlobBuilder::new(policy_id, ck.meta.task_hash)
        .action_space(ck.meta.action_space())
        .activation(Activation::Tanh)
        .output_activation(Activation::Identity);
    for s in &layout.actor {
        b = b.layer(
            s.n_in,
            s.n_out,
            &ck.theta[s.w_off..s.w_off + s.n_in * s.n_out],
            &ck.theta[s.b_off..s.b_off + s.n_out],
        );
    }
    let (mean, std, clip): (Vec<f32>, Vec<f32>, f32) = if ck.meta.ppo.norm_obs {
        (
            ck.meta.obs_rms.mean.iter().map(|m| *m as f32).collect(),
            ck.meta
                .obs_rms
                .var
                .iter()
                .map(|v| (v + ObsNormalizer::EPS).sqrt() as f32)
                .collect(),
            ck.meta.ppo.clip_obs,
        )
    } else {
        (vec![0.0; spec.obs_dim], vec![1.0; spec.obs_dim], f32::MAX)
    };
    b.obs_normalization(&mean, &std, clip)
        .action_scaling(&vec![1.0; spec.act_dim], 1.0)
}

/// The checkpoint's policy as a sealed, validated blob.
///
/// # Errors
/// [`ExportError::Build`].
pub fn export_blob(ck: &Checkpoint, policy_id: u64) -> Result<Box<PolicyBlob>, ExportError> {
    Ok(builder(ck, policy_id).build()?)
}

/// The normaliser the exported blob applies (for evaluating exactly what rt-core runs).
pub fn blob_normalizer(blob: &PolicyBlob) -> ObsNormalizer {
    let n = blob.obs_dim as usize;
    ObsNormalizer {
        mean: blob.obs_mean[..n].to_vec(),
        inv_std: blob.obs_std[..n].iter().map(|s| 1.0 / s).collect(),
        clip: blob.obs_clip,
    }
}

/// The blob's bytes (the blob-file format of [`PolicyBlob::as_bytes`]).
pub fn blob_bytes(blob: &PolicyBlob) -> &[u8] {
    blob.as_bytes()
}

/// Parses and validates blob bytes ([`PolicyBlob::from_bytes`]).
///
/// # Errors
/// [`ExportError::Invalid`] for a wrong length or a blob that fails validation.
pub fn blob_from_bytes(bytes: &[u8]) -> Result<Box<PolicyBlob>, ExportError> {
    PolicyBlob::from_bytes(bytes).map_err(ExportError::Invalid)
}

/// Writes a blob file atomically.
///
/// # Errors
/// [`ExportError::Write`].
pub fn write_blob(path: &Path, blob: &PolicyBlob) -> Result<(), ExportError> {
    Ok(write_atomic(path, blob_bytes(blob))?)
}

/// Reads and validates a blob file.
///
/// # Errors
/// [`ExportError`].
pub fn read_blob(path: &Path) -> Result<Box<PolicyBlob>, ExportError> {
    let bytes = std::fs::read(path).map_err(|source| ExportError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    blob_from_bytes(&bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint::{CheckpointMeta, FORMAT, StatsState};
    use crate::net::NetSpec;
    use crate::ppo::PpoConfig;
    use crate::random::RngState;

    /// The policy id as it was computed before the shared hasher (FNV-1a written out here).
    fn old_policy_id(ck: &Checkpoint) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |b: &[u8]| {
            for x in b {
                h ^= u64::from(*x);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        for w in &ck.theta {
            eat(&w.to_le_bytes());
        }
        eat(&ck.meta.steps.to_le_bytes());
        eat(&ck.meta.task_hash.to_le_bytes());
        h.max(1)
    }

    #[test]
    fn policy_id_is_unchanged_by_the_shared_fnv_hasher() {
        let stats = StatsState {
            mean: vec![0.0],
            var: vec![1.0],
            count: 1.0,
        };
        let rng = RngState {
            seed: [0; 32],
            stream: 0,
            word_pos: [0, 0],
        };
        let mut ck = Checkpoint {
            meta: CheckpointMeta {
                format: FORMAT.into(),
                spec: NetSpec {
                    obs_dim: 1,
                    act_dim: 1,
                    hidden: vec![1],
                },
                ppo: PpoConfig::default(),
                seed: 1,
                task_hash: 0xfeed_beef_0123_4567,
                steps: 123_456,
                iteration: 0,
                adam_t: 0,
                obs_rms: stats.clone(),
                ret_rms: stats,
                trainer_rng: rng,
                env_rngs: vec![],
                eval: None,
                best_eval: None,
                action_space: 0,
            },
            theta: vec![0.5, -1.25, 3.0e-7, f32::MIN_POSITIVE, -0.0, 1.0e9],
            adam_m: vec![],
            adam_v: vec![],
        };
        assert_eq!(policy_id_for(&ck), old_policy_id(&ck));
        ck.theta.clear();
        ck.meta.steps = 0;
        assert_eq!(policy_id_for(&ck), old_policy_id(&ck));
    }
}
