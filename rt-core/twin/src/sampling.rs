//! Verified sampling: when a policy's deterministic rollout fails, roll out K perturbed
//! variants of it in the twin, verify each exactly as the deterministic one (a whole
//! episode under the task's contact rule: success and no contact), and keep the best that
//! passes — fewest steps to the goal, then the largest clearance.
//!
//! Candidate 0 is the deterministic rollout (the policy's mean action). Candidate `i ≥ 1`
//! adds Gaussian noise to each action component: an AR(1) sequence with stationary standard
//! deviation `noise_sigma` (in action units, where the action range is `[-1, 1]`, i.e. a
//! fraction of the largest step `action.scale_m`) and step-to-step correlation
//! `noise_correlation` — correlated noise bends the whole approach one way (round a box on
//! its left or its right), white noise mostly averages out. A share `via_point_share` of the
//! candidates instead perturbs the start of the goal approach: the TCP first heads straight
//! for a random via point (part of the way to the goal, up to [`VIA_LATERAL_M`] to the side
//! and [`VIA_UP_M`] up) for at most [`VIA_MAX_STEPS`] steps, then the policy drives, without
//! noise. Each candidate's noise comes
//! from its own `ChaCha8` stream seeded by `(seed, i)`, so candidate `i` is the same episode
//! whatever the thread count, the budget or the other candidates: runs are reproducible.
//!
//! The candidates run on `threads` scoped threads (candidate `i` on thread `i mod threads`,
//! each with its own [`TwinEnv`] and waypoint buffers made once in [`Sampler::new`]); a
//! deadline stops each thread before its next candidate. The same code serves rt-core's twin
//! worker (in its time budget) and `unseen-worlds --samples` (pass@K).
//!
//! # Example
//! ```no_run
//! use std::path::Path;
//! use shm_schemas::scene_file::SceneFile;
//! use twin::{RobotModel, Sampler, SamplingSettings, Scene, TaskConfig, TwinEnv};
//!
//! let model = RobotModel::load(Path::new("assets/xarm5.urdf"))?;
//! let task = TaskConfig::load(Path::new("assets/task.toml"))?;
//! let scene = Scene::from_file(&SceneFile::load(Path::new("assets/scenes/tall_box.toml"))?)?;
//! let env = TwinEnv::new(model, task);
//! let line = env.straight_line_policy();
//! let settings = SamplingSettings { candidates: 32, ..SamplingSettings::default() };
//! let mut sampler = Sampler::new(&env, settings);
//! let report = sampler.run(&scene, &|obs| line.act(obs), 0, None);
//! if let Some(best) = report.best {
//!     let _waypoints = sampler.waypoints(best.index);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::env::{EpisodeSummary, TwinEnv, rollout_until};
use super::task::MAX_EPISODE_STEPS;
use super::{ACT_DIM, Joints, OBS_DIM};

/// Most candidates one [`Sampler`] holds.
pub const MAX_SAMPLES: usize = 256;

/// Most threads one [`Sampler`] uses.
pub const MAX_SAMPLE_THREADS: usize = 16;

/// A via point lies up to this far to either side of the start→goal line, m.
pub const VIA_LATERAL_M: f64 = 0.25;

/// A via point lies up to this far above the start→goal line, m.
pub const VIA_UP_M: f64 = 0.25;

/// Most steps spent heading for a via point.
pub const VIA_MAX_STEPS: u32 = 40;

/// A via point counts as reached this close, m.
const VIA_REACHED_M: f64 = 0.02;

/// How the candidates are drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplingSettings {
    /// K: candidates, the deterministic rollout (candidate 0) included; 1..=[`MAX_SAMPLES`].
    pub candidates: usize,
    /// Stationary standard deviation of the action noise, in action units (the action range
    /// is `[-1, 1]`, times `action.scale_m`); ≥ 0.
    pub noise_sigma: f64,
    /// Step-to-step correlation of the noise, 0 (white) ..< 1.
    pub noise_correlation: f64,
    /// Seed of every candidate's noise stream.
    pub seed: u64,
    /// Share of the perturbed candidates that start with a via point instead of action
    /// noise, 0..=1.
    pub via_point_share: f64,
    /// Threads the candidates run on, 1..=[`MAX_SAMPLE_THREADS`].
    pub threads: usize,
}

impl Default for SamplingSettings {
    fn default() -> Self {
        Self {
            candidates: 32,
            noise_sigma: 0.3,
            noise_correlation: 0.9,
            seed: 0,
            via_point_share: 0.5,
            threads: 2,
        }
    }
}

impl SamplingSettings {
    /// Checks the ranges; the offending field's name on error.
    ///
    /// # Errors
    /// The field (`candidates`, `noise_sigma`, `noise_correlation`, `threads`) and why.
    pub fn validate(&self) -> Result<(), (&'static str, &'static str)> {
        if !(1..=MAX_SAMPLES).contains(&self.candidates) {
            return Err(("candidates", "must be within 1..=256"));
        }
        if !(self.noise_sigma.is_finite() && (0.0..=2.0).contains(&self.noise_sigma)) {
            return Err(("noise_sigma", "must be within 0..=2 (action units)"));
        }
        if !(self.noise_correlation.is_finite() && (0.0..1.0).contains(&self.noise_correlation)) {
            return Err(("noise_correlation", "must be within 0..1"));
        }
        if !(self.via_point_share.is_finite() && (0.0..=1.0).contains(&self.via_point_share)) {
            return Err(("via_point_share", "must be within 0..=1"));
        }
        if !(1..=MAX_SAMPLE_THREADS).contains(&self.threads) {
            return Err(("threads", "must be within 1..=16"));
        }
        Ok(())
    }
}

/// One candidate's verified episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Its index (0: the deterministic rollout).
    pub index: usize,
    /// Its episode.
    pub summary: EpisodeSummary,
}

impl Sample {
    /// The episode reached the goal with no contact: what the lookahead passes.
    pub fn passed(&self) -> bool {
        self.summary.success && self.summary.safe
    }
}

/// What one [`Sampler::run`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleReport {
    /// Candidates rolled out (the deadline may stop before all).
    pub tried: usize,
    /// Of those, the ones that passed.
    pub passed: usize,
    /// The best that passed: fewest steps, then the largest clearance, then the lowest
    /// index.
    pub best: Option<Sample>,
    /// The deadline stopped the run before every candidate was tried.
    pub cut_by_deadline: bool,
    /// Wall time, s.
    pub elapsed_s: f64,
}

/// One candidate's slot: its episode and waypoints.
#[derive(Debug, Clone)]
struct Slot {
    summary: Option<EpisodeSummary>,
    waypoints: heapless::Vec<Joints, MAX_EPISODE_STEPS>,
}

/// K perturbed rollouts of a policy on a few threads; see the module docs.
#[derive(Debug, Clone)]
pub struct Sampler {
    settings: SamplingSettings,
    /// One environment per thread.
    envs: Vec<TwinEnv>,
    /// One slot per candidate.
    slots: Vec<Slot>,
}

/// Splits a 64-bit value into a well-mixed one (SplitMix64's finaliser).
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A standard normal draw (Box–Muller).
fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Rolls candidate `index` out in `env` into `slot`.
fn roll_candidate<P>(
    env: &mut TwinEnv,
    scene: &super::Scene,
    policy: &P,
    settings: &SamplingSettings,
    index: usize,
    slot: &mut Slot,
) where
    P: Fn(&[f32; OBS_DIM]) -> [f32; ACT_DIM],
{
    let mut rng = ChaCha8Rng::seed_from_u64(mix(settings.seed ^ mix(index as u64)));
    let via = index > 0 && rng.random::<f64>() < settings.via_point_share;
    let summary = if via {
        let cfg = env.config();
        let scale_m = cfg.action.scale_m;
        let start = env.start_tcp_m();
        let goal = scene.goal_target_m(cfg.success.goal_hover_m);
        let along = goal - start;
        let side = nalgebra::Vector3::new(-along.y, along.x, 0.0);
        let side = if side.norm() > 1e-9 {
            side / side.norm()
        } else {
            nalgebra::Vector3::y()
        };
        let u = 0.2 + 0.5 * rng.random::<f64>();
        let lateral = VIA_LATERAL_M * (2.0 * rng.random::<f64>() - 1.0);
        let up = VIA_UP_M * rng.random::<f64>();
        let point = start + along * u + side * lateral + nalgebra::Vector3::z() * up;
        let mut heading = true;
        let mut steps = 0u32;
        rollout_until(
            env,
            scene,
            |obs| {
                let tcp =
                    nalgebra::Vector3::new(f64::from(obs[3]), f64::from(obs[4]), f64::from(obs[5]));
                let to = point - tcp;
                heading &= to.norm() > VIA_REACHED_M && steps < VIA_MAX_STEPS;
                steps += 1;
                if heading {
                    let a = to / scale_m;
                    let biggest = a.amax().max(1.0);
                    [
                        (a.x / biggest) as f32,
                        (a.y / biggest) as f32,
                        (a.z / biggest) as f32,
                    ]
                } else {
                    policy(obs)
                }
            },
            Some(&mut slot.waypoints),
            true,
        )
    } else if index == 0 || settings.noise_sigma == 0.0 {
        rollout_until(env, scene, policy, Some(&mut slot.waypoints), true)
    } else {
        let rho = settings.noise_correlation;
        let sigma = settings.noise_sigma;
        let fresh = sigma * (1.0 - rho * rho).sqrt();
        let mut noise: [f64; ACT_DIM] = std::array::from_fn(|_| sigma * gauss(&mut rng));
        rollout_until(
            env,
            scene,
            |obs| {
                let mut a = policy(obs);
                for (ak, nk) in a.iter_mut().zip(noise.iter_mut()) {
                    *ak += *nk as f32;
                    *nk = rho * *nk + fresh * gauss(&mut rng);
                }
                a
            },
            Some(&mut slot.waypoints),
            true,
        )
    };
    slot.summary = Some(summary);
}

impl Sampler {
    /// Over (a copy of) `env` — its model and task — with `settings`; every environment and
    /// buffer is made here. `settings` is clamped into its ranges
    /// ([`SamplingSettings::validate`] says which are out).
    pub fn new(env: &TwinEnv, settings: SamplingSettings) -> Self {
        let settings = SamplingSettings {
            candidates: settings.candidates.clamp(1, MAX_SAMPLES),
            threads: settings.threads.clamp(1, MAX_SAMPLE_THREADS),
            ..settings
        };
        let threads = settings.threads.min(settings.candidates);
        Self {
            settings,
            envs: (0..threads).map(|_| env.clone()).collect(),
            slots: (0..settings.candidates)
                .map(|_| Slot {
                    summary: None,
                    waypoints: heapless::Vec::new(),
                })
                .collect(),
        }
    }

    /// The settings in use.
    pub fn settings(&self) -> &SamplingSettings {
        &self.settings
    }

    /// Rolls candidates `first..K` of `policy` out in `scene` (`first = 1` when the caller
    /// has already run the deterministic rollout and seen it fail), each thread stopping
    /// before its next candidate once `deadline` has passed, and reports the best that
    /// passed.
    ///
    /// # Performance
    /// One episode per candidate, spread over the threads (spawned for the call; none with
    /// one thread). No allocation but the threads' and the partition's.
    pub fn run<P>(
        &mut self,
        scene: &super::Scene,
        policy: &P,
        first: usize,
        deadline: Option<Instant>,
    ) -> SampleReport
    where
        P: Fn(&[f32; OBS_DIM]) -> [f32; ACT_DIM] + Sync,
    {
        let t0 = Instant::now();
        let settings = self.settings;
        for slot in &mut self.slots {
            slot.summary = None;
            slot.waypoints.clear();
        }
        let threads = self.envs.len();
        let late = || deadline.is_some_and(|d| Instant::now() >= d);
        if threads == 1 {
            let env = &mut self.envs[0];
            for (index, slot) in self.slots.iter_mut().enumerate().skip(first) {
                if late() {
                    break;
                }
                roll_candidate(env, scene, policy, &settings, index, slot);
            }
        } else {
            let mut parts: Vec<Vec<(usize, &mut Slot)>> = (0..threads)
                .map(|_| Vec::with_capacity(settings.candidates / threads + 1))
                .collect();
            for (index, slot) in self.slots.iter_mut().enumerate().skip(first) {
                parts[index % threads].push((index, slot));
            }
            std::thread::scope(|s| {
                for (env, part) in self.envs.iter_mut().zip(parts) {
                    let settings = &settings;
                    let late = &late;
                    s.spawn(move || {
                        for (index, slot) in part {
                            if late() {
                                break;
                            }
                            roll_candidate(env, scene, policy, settings, index, slot);
                        }
                    });
                }
            });
        }
        let mut report = SampleReport {
            tried: 0,
            passed: 0,
            best: None,
            cut_by_deadline: false,
            elapsed_s: 0.0,
        };
        for (index, slot) in self.slots.iter().enumerate().skip(first) {
            let Some(summary) = slot.summary else {
                report.cut_by_deadline = true;
                continue;
            };
            report.tried += 1;
            let sample = Sample { index, summary };
            if !sample.passed() {
                continue;
            }
            report.passed += 1;
            if report.best.is_none_or(|b| better(&sample, &b)) {
                report.best = Some(sample);
            }
        }
        report.elapsed_s = t0.elapsed().as_secs_f64();
        report
    }

    /// The passing candidates of the last run, best first (see [`SampleReport::best`]).
    pub fn ranked(&self) -> Vec<Sample> {
        let mut v: Vec<Sample> = self
            .slots
            .iter()
            .enumerate()
            .filter_map(|(index, s)| s.summary.map(|summary| Sample { index, summary }))
            .filter(Sample::passed)
            .collect();
        v.sort_by(|a, b| {
            if better(a, b) {
                std::cmp::Ordering::Less
            } else if better(b, a) {
                std::cmp::Ordering::Greater
            } else {
                std::cmp::Ordering::Equal
            }
        });
        v
    }

    /// The waypoints (joints after every step) of candidate `index` in the last run; empty
    /// when it was not rolled out.
    pub fn waypoints(&self, index: usize) -> &[Joints] {
        self.slots.get(index).map_or(&[], |s| &s.waypoints[..])
    }

    /// Candidate `index`'s episode in the last run, when it was rolled out.
    pub fn summary(&self, index: usize) -> Option<EpisodeSummary> {
        self.slots.get(index).and_then(|s| s.summary)
    }
}

/// `a` ranks before `b`: fewer steps, then more clearance, then the lower index.
fn better(a: &Sample, b: &Sample) -> bool {
    (a.summary.steps, -a.summary.min_distance_m, a.index)
        .partial_cmp(&(b.summary.steps, -b.summary.min_distance_m, b.index))
        .is_some_and(|o| o == std::cmp::Ordering::Less)
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use shm_schemas::scene_file::SceneFile;

    use super::*;
    use crate::{RobotModel, Scene, TaskConfig, rollout};

    fn assets() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets")
    }

    fn env() -> TwinEnv {
        let model = RobotModel::load(&assets().join("xarm5.urdf")).unwrap();
        let task = TaskConfig::load(&assets().join("task.toml")).unwrap();
        TwinEnv::new(model, task)
    }

    fn scene(name: &str) -> Scene {
        Scene::from_file(&SceneFile::load(&assets().join("scenes").join(name)).unwrap()).unwrap()
    }

    /// Candidate 0 is the deterministic rollout; every candidate is the same episode
    /// whatever the thread count; the best is the fewest steps among those that passed.
    #[test]
    fn candidates_are_reproducible_and_the_first_is_the_deterministic_rollout() {
        let env = env();
        let scene = scene("small_box.toml");
        let line = env.straight_line_policy();
        let policy = |o: &[f32; OBS_DIM]| line.act(o);
        let settings = SamplingSettings {
            candidates: 12,
            ..SamplingSettings::default()
        };
        let mut one = Sampler::new(
            &env,
            SamplingSettings {
                threads: 1,
                ..settings
            },
        );
        let mut three = Sampler::new(
            &env,
            SamplingSettings {
                threads: 3,
                ..settings
            },
        );
        let a = one.run(&scene, &policy, 0, None);
        let b = three.run(&scene, &policy, 0, None);
        assert_eq!(a.tried, 12);
        assert_eq!((a.tried, a.passed, a.best), (b.tried, b.passed, b.best));
        for i in 0..12 {
            assert_eq!(one.waypoints(i), three.waypoints(i), "candidate {i}");
            assert_eq!(one.summary(i), three.summary(i));
        }
        let mut e = env.clone();
        let det = rollout(&mut e, &scene, policy, None);
        assert_eq!(one.summary(0), Some(det));
        assert_ne!(one.waypoints(1), one.waypoints(0));
        let ranked = one.ranked();
        assert_eq!(ranked.len(), a.passed);
        assert_eq!(ranked.first().copied(), a.best);
        assert!(
            ranked
                .windows(2)
                .all(|w| w[0].summary.steps <= w[1].summary.steps)
        );
        // Skipping the deterministic candidate leaves its slot empty.
        let c = one.run(&scene, &policy, 1, None);
        assert_eq!(c.tried, 11);
        assert!(one.summary(0).is_none() && one.waypoints(0).is_empty());
    }

    /// A deadline already passed stops every thread before its first candidate.
    #[test]
    fn a_passed_deadline_tries_nothing() {
        let env = env();
        let scene = scene("small_box.toml");
        let line = env.straight_line_policy();
        let mut s = Sampler::new(&env, SamplingSettings::default());
        let r = s.run(&scene, &|o| line.act(o), 1, Some(Instant::now()));
        assert_eq!(
            (r.tried, r.passed, r.best, r.cut_by_deadline),
            (0, 0, None, true)
        );
    }

    #[test]
    fn out_of_range_settings_name_their_field() {
        let ok = SamplingSettings::default();
        assert_eq!(ok.validate(), Ok(()));
        let cases = [
            (
                SamplingSettings {
                    candidates: 0,
                    ..ok
                },
                "candidates",
            ),
            (
                SamplingSettings {
                    candidates: 257,
                    ..ok
                },
                "candidates",
            ),
            (
                SamplingSettings {
                    noise_sigma: f64::NAN,
                    ..ok
                },
                "noise_sigma",
            ),
            (
                SamplingSettings {
                    noise_correlation: 1.0,
                    ..ok
                },
                "noise_correlation",
            ),
            (SamplingSettings { threads: 0, ..ok }, "threads"),
            (
                SamplingSettings {
                    via_point_share: 1.5,
                    ..ok
                },
                "via_point_share",
            ),
        ];
        for (s, field) in cases {
            assert_eq!(s.validate().unwrap_err().0, field);
        }
    }
}
