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

use std::path::Path;

use shm_schemas::{Activation, PolicyBlob, PolicyBlobBuilder, PolicyBuildError};

use crate::checkpoint::{Checkpoint, CheckpointError, write_atomic};
use crate::normalize::ObsNormalizer;

/// Why a blob could not be made, written or read.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The builder rejected the network.
    #[error("policy blob: {0}")]
    Build(#[from] PolicyBuildError),
    /// Writing failed.
    #[error("{0}")]
    Write(#[from] CheckpointError),
    /// Reading failed.
    #[error("cannot read {path}: {source}")]
    Read {
        /// File.
        path: String,
        /// OS error.
        source: std::io::Error,
    },
    /// The file is not a valid blob.
    #[error("invalid policy blob file: {0}")]
    Invalid(String),
}

/// A builder holding the checkpoint's actor and normalisation.
pub fn builder(ck: &Checkpoint, policy_id: u64) -> PolicyBlobBuilder {
    let spec = &ck.meta.spec;
    let layout = spec.layout();
    let mut b = PolicyBlobBuilder::new(policy_id, ck.meta.task_hash)
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
    PolicyBlob::from_bytes(bytes).map_err(|e| ExportError::Invalid(format!("{e}")))
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
        path: path.display().to_string(),
        source,
    })?;
    blob_from_bytes(&bytes)
}
