//! Generalised advantage estimation, GAE(λ), over a time-major rollout.

/// Generalised advantage estimation over a time-major `[T][n_envs]` rollout.
///
/// `ends[i]` marks that the episode ended after step `i` (the next stored step belongs to a
/// new episode; a truncation's bootstrap value must already be folded into `rewards[i]`).
/// `last_values[e]` is the value of the observation following the rollout.
/// Returns `(advantages, returns)` with `returns = advantages + values`.
pub fn gae(
    rewards: &[f32],
    values: &[f32],
    ends: &[bool],
    last_values: &[f32],
    gamma: f32,
    lambda: f32,
) -> (Vec<f32>, Vec<f32>) {
    let n = last_values.len();
    let len = rewards.len();
    let mut adv = vec![0.0f32; len];
    if n == 0 {
        return (adv, Vec::new());
    }
    let t_len = len / n;
    let mut running = vec![0.0f32; n];
    for t in (0..t_len).rev() {
        for e in 0..n {
            let i = t * n + e;
            let next_v = if t + 1 == t_len {
                last_values[e]
            } else {
                values[i + n]
            };
            let nonterminal = if ends[i] { 0.0 } else { 1.0 };
            let delta = rewards[i] + gamma * next_v * nonterminal - values[i];
            running[e] = delta + gamma * lambda * nonterminal * running[e];
            adv[i] = running[e];
        }
    }
    let ret = adv.iter().zip(values).map(|(a, v)| a + v).collect();
    (adv, ret)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gae_matches_a_hand_computed_case() {
        // One env, three steps, episode ends after step 1 (terminal), then a new one.
        let r = [1.0f32, 2.0, 3.0];
        let v = [0.5f32, 1.0, 1.5];
        let ends = [false, true, false];
        let (g, l) = (0.9f32, 0.8f32);
        let (adv, ret) = gae(&r, &v, &ends, &[2.0], g, l);
        // t=2: δ = 3 + 0.9*2 - 1.5 = 3.3, A = 3.3
        // t=1: δ = 2 + 0 - 1 = 1 (terminal), A = 1
        // t=0: δ = 1 + 0.9*1 - 0.5 = 1.4, A = 1.4 + 0.72*1 = 2.12
        let want = [2.12f32, 1.0, 3.3];
        for i in 0..3 {
            assert!((adv[i] - want[i]).abs() < 1e-5, "adv[{i}] = {}", adv[i]);
            assert!((ret[i] - (want[i] + v[i])).abs() < 1e-5);
        }
    }

    #[test]
    fn gae_keeps_environments_apart_in_time_major_layout() {
        // Two envs interleaved [t][e]; env 1 is the same as env 0 shifted by rewards.
        let r = [1.0f32, 0.0, 1.0, 0.0];
        let v = [0.0f32; 4];
        let (adv, _) = gae(&r, &v, &[false; 4], &[0.0, 0.0], 1.0, 1.0);
        assert_eq!(adv, vec![2.0, 0.0, 1.0, 0.0]);
    }
}
