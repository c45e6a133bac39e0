//! The scenario director: plays a world script against the running system and measures the
//! self-improving loop (the research system's Algorithm 1) from the outside.
//!
//! Scene 0 is in force at start. When the arm has reached scene k's goal (or scene k's
//! phase timed out), and scene k+1's `at_s` has passed, the director asks the launcher to
//! switch the world to scene k+1 (ground truth in `xarm-sim`, the synthetic camera's view).
//! From then on it timestamps, from what the processes publish: the first detection of the
//! new scene, the first verdict on it (and whether it flagged a collision before the arm had
//! moved), the retrain request, the new policy, the arm moving again, and the goal reached.
//! In a scene with moving boxes it also marks when each box sets off and comes to rest
//! (from the scene file's keyframes, counted from the switch), when the arm stops for an
//! obstacle (`paused`: a controlled stop whose reason is the shield's, which is how rt-core
//! reports a plan its twin revoked) and when it moves on again (`resumed`).
//!
//! The director is a pure state machine over [`Observations`] and a clock value, so it is
//! tested without processes; the `foresight` binary feeds it.

use nalgebra::Vector3;
use serde::Serialize;
use shm_schemas::scene_file::{Keyframe, SceneFile};
use shm_schemas::{
    Executor, PhaseCode, RetrainPhase, RetrainProgress, RetrainRequest, RobotState, StopReason,
    TwinVerdict,
};

use super::acts::{ActMark, ActRecord, ActSummary};
use super::observer::{Observations, SeenScene};
use super::report::{Outcome, PathSample, Summary};
use super::separation::{SeparationSample, SeparationTrace, separation_m};
use twin::InfeasibleReason;
use twin::max_joint_gap_rad;

/// Director settings.
#[derive(Debug, Clone)]
pub struct ScenarioConfig {
    /// The world: `(at_s, scene)`, first at 0.
    pub world: Vec<(f64, SceneFile)>,
    /// TCP within this of the goal target = reached (the task's success tolerance, m).
    pub goal_tolerance_m: f64,
    /// The goal target is this far above the goal cube's top (m).
    pub goal_hover_m: f64,
    /// Longest a scene may take before the director gives up on its goal (s).
    pub phase_timeout_s: f64,
    /// The arm must be still this long before the world changes (s).
    pub settle_s: f64,
    /// Whether rt-core gates motion on the lookahead (reported only).
    pub lookahead: bool,
    /// Where the arm rests between episodes (rt-core's `return_home`: the task's start
    /// posture), rad; the world changes only once the arm has settled there. `None`: the
    /// world changes wherever the arm has settled.
    pub home_q_rad: Option<[f64; 5]>,
    /// The goal comes from the ROS 2 `Reach` action (`--goal-source action`): a scene's goal
    /// cube is not the arm's goal, so a scene ends only at its phase timeout (or when the
    /// run is stopped), never on reaching the cube or on an infeasible answer.
    pub goals_from_action: bool,
}

/// Joints within this of home count as home, rad.
const HOME_TOLERANCE_RAD: f64 = 0.02;

/// What the launcher must do now.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Put scene `index` of the world in force.
    SwitchScene(usize),
    /// The scenario is over (goal of the last scene reached, or given up).
    Finish,
}

/// One line of the timeline (`timeline.jsonl`).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TimelineEvent {
    /// Time since the launcher started (s).
    pub t_s: f64,
    /// Event kind (`world_change`, `detection`, `verdict`, `retrain_request`,
    /// `retrain_progress`, `policy_swap`, `motion`, `goal_reached`, `timeout`,
    /// `obstacle_moves`, `obstacle_stops`, `paused`, `resumed`, …).
    pub kind: &'static str,
    /// Human-readable detail.
    pub detail: String,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    WaitingForSystem,
    Reaching { scene: usize, since_s: f64 },
    Done,
}

/// The state machine.
#[derive(Debug)]
pub struct Director {
    cfg: ScenarioConfig,
    phase: Phase,
    events: Vec<TimelineEvent>,
    path: Vec<PathSample>,
    last_state: Option<RobotState>,
    still_since_s: Option<f64>,
    active_policy: Option<u64>,
    // facts about the last world change
    change_s: Option<f64>,
    joints_at_change: Option<[f64; 5]>,
    detect_s: Option<f64>,
    /// The first settled frame showing the new scene (the twin approves plans only on one).
    settled_s: Option<f64>,
    /// The first plan approved on the new scene once it was settled.
    approved_s: Option<f64>,
    verdict_s: Option<f64>,
    request_s: Option<f64>,
    published_s: Option<f64>,
    motion_s: Option<f64>,
    predicted_before_motion: bool,
    moved_since_change: bool,
    approved_after_change: bool,
    policy_swaps: u64,
    goals_reached: Vec<bool>,
    /// Per scene: the learner's "no safe way" verdict, in words.
    infeasible: Vec<Option<String>>,
    /// rt-core's "a box has taken the goal" verdicts, in words (`summary.json`'s
    /// `goal_taken`).
    goal_taken: Vec<String>,
    /// Per scene: retraining budgets that ran out without a passing policy.
    budgets_exhausted: Vec<u32>,
    /// Per scene: verdicts that refused a plan (lookahead failed or not approved).
    refused_verdicts: Vec<u32>,
    /// Per scene: whether the first verdict after the scene was seen approved a plan.
    zero_shot: Vec<Option<bool>>,
    /// Per scene: what moved the arm under an approved plan (a policy, the planner), in the
    /// order they first did.
    moved_by: Vec<Vec<Executor>>,
    /// Per scene: the arm's closest TCP approach to the goal target seen, m.
    closest_m: Vec<f64>,
    p99_us: Option<f64>,
    last_progress_print_s: f64,
    /// Since when the arm has been stopped for an obstacle (launcher time, s).
    paused_since_s: Option<f64>,
    /// Per scene: the arm's stops for an obstacle.
    pauses: Vec<u32>,
    /// The longest pause that ended (s).
    longest_pause_s: Option<f64>,
    /// The scene in force's box motions still to be marked: (launcher time s, kind, detail).
    box_events: Vec<(f64, &'static str, String)>,
    /// Per scene: the ids of the retrain requests rt-core made while it was in force. A
    /// progress message counts for a scene only when it answers one of them: a late answer
    /// to an earlier scene's request (a learner still finishing it) can neither end nor
    /// relabel the current scene ("infeasible", "published").
    requests: Vec<Vec<u64>>,
    /// Per scene: progress messages ignored because they answered another scene's request.
    stale_progress: Vec<u32>,
    /// When the scene in force came into force (launcher time, s): the origin of its boxes'
    /// paths.
    scene_since_s: f64,
    /// The arm's separation from the world's true boxes over the run.
    separation: SeparationTrace,
    /// Per scene: the act's loop (requests, published, accepted, refused policies).
    acts: Vec<ActRecord>,
}

/// A box motion's timeline mark: box `i` at keyframe `k` of a scene put in force at `t_s`.
fn box_mark(
    t_s: f64,
    i: usize,
    k: Keyframe,
    kind: &'static str,
    verb: &str,
) -> (f64, &'static str, String) {
    let c = k.center_m;
    let detail = format!(
        "box {i} {verb} ({:.2}, {:.2}, {:.2}) m (+{:.2} s)",
        c[0], c[1], c[2], k.at_s
    );
    (t_s + k.at_s, kind, detail)
}

fn tcp_of(state: &RobotState) -> Vector3<f64> {
    Vector3::from(state.tcp_m)
}

impl Director {
    /// A director for `cfg`.
    pub fn new(cfg: ScenarioConfig) -> Self {
        let n = cfg.world.len();
        Self {
            cfg,
            phase: Phase::WaitingForSystem,
            events: Vec::new(),
            path: Vec::new(),
            last_state: None,
            still_since_s: None,
            active_policy: None,
            change_s: None,
            joints_at_change: None,
            detect_s: None,
            settled_s: None,
            approved_s: None,
            verdict_s: None,
            request_s: None,
            published_s: None,
            motion_s: None,
            predicted_before_motion: false,
            moved_since_change: false,
            approved_after_change: false,
            policy_swaps: 0,
            goals_reached: vec![false; n],
            infeasible: vec![None; n],
            goal_taken: Vec::new(),
            budgets_exhausted: vec![0; n],
            refused_verdicts: vec![0; n],
            zero_shot: vec![None; n],
            moved_by: vec![Vec::new(); n],
            closest_m: vec![f64::INFINITY; n],
            p99_us: None,
            last_progress_print_s: f64::NEG_INFINITY,
            paused_since_s: None,
            pauses: vec![0; n],
            longest_pause_s: None,
            box_events: Vec::new(),
            requests: vec![Vec::new(); n],
            stale_progress: vec![0; n],
            scene_since_s: 0.0,
            separation: SeparationTrace::default(),
            acts: vec![ActRecord::default(); n],
        }
    }

    /// The timeline so far.
    pub fn events(&self) -> &[TimelineEvent] {
        &self.events
    }

    /// The executed TCP path so far.
    pub fn path(&self) -> &[PathSample] {
        &self.path
    }

    /// The arm's separation from the world's true boxes so far.
    pub fn separation(&self) -> &SeparationTrace {
        &self.separation
    }

    /// When each world change happened (launcher time, s).
    pub fn world_changes_s(&self) -> Vec<f64> {
        self.events
            .iter()
            .filter(|e| e.kind == "world_change")
            .map(|e| e.t_s)
            .collect()
    }

    /// The scene index in force.
    pub fn scene_index(&self) -> usize {
        match self.phase {
            Phase::Reaching { scene, .. } => scene,
            Phase::WaitingForSystem => 0,
            Phase::Done => self.cfg.world.len().saturating_sub(1),
        }
    }

    /// Whether the scenario is over.
    pub fn is_done(&self) -> bool {
        self.phase == Phase::Done
    }

    fn log(&mut self, t_s: f64, kind: &'static str, detail: String) {
        self.events.push(TimelineEvent { t_s, kind, detail });
    }

    fn target(&self, scene: usize) -> Vector3<f64> {
        let g = &self.cfg.world[scene].1.goal;
        Vector3::new(
            g.center_m[0],
            g.center_m[1],
            g.center_m[2] + g.size_m / 2.0 + self.cfg.goal_hover_m,
        )
    }

    fn tallest(scene: &SceneFile) -> f64 {
        scene
            .obstacles
            .iter()
            .map(|b| b.size_m[2])
            .fold(0.0, f64::max)
    }

    /// Feeds one poll's observations at launcher time `t_s`; returns what to do.
    pub fn step(&mut self, t_s: f64, obs: &Observations) -> Vec<Action> {
        let mut actions = Vec::new();
        let scene_idx = self.scene_index();
        self.mark_box_motions(t_s);
        for s in &obs.states {
            self.on_state(t_s, s, scene_idx);
        }
        if let Some(seen) = obs.scene {
            self.on_scene_seen(t_s, &seen, scene_idx);
        }
        for v in &obs.verdicts {
            self.on_verdict(t_s, v, scene_idx);
        }
        for r in &obs.retrain_requests {
            self.on_retrain_request(t_s, r, scene_idx);
        }
        for p in &obs.progress {
            self.on_progress(t_s, p, scene_idx);
        }
        if obs.rejected > 0 {
            self.log(
                t_s,
                "rejected",
                format!("{} malformed sample(s) rejected", obs.rejected),
            );
        }
        self.advance_phase(t_s, &mut actions);
        actions
    }

    /// The camera's view of the scene after a world change: detection time.
    fn on_scene_seen(&mut self, t_s: f64, seen: &SeenScene, scene_idx: usize) {
        if self.change_s.is_none() || self.settled_s.is_some() {
            return;
        }
        let want = &self.cfg.world[scene_idx].1;
        let height_ok = (f64::from(seen.tallest_obstacle_m) - Self::tallest(want)).abs() < 0.03;
        let goal_ok = seen.goal_m.is_some_and(|g| {
            (f64::from(g[0]) - want.goal.center_m[0]).abs() < 0.03
                && (f64::from(g[1]) - want.goal.center_m[1]).abs() < 0.03
        });
        if !(height_ok && goal_ok) {
            return;
        }
        let dt = t_s - self.change_s.unwrap_or(t_s);
        if self.detect_s.is_none() {
            self.detect_s = Some(t_s);
            self.log(
                t_s,
                "detection",
                format!(
                    "camera sees the new scene (+{dt:.3} s): tallest obstacle {:.3} m, {} obstacle(s)",
                    seen.tallest_obstacle_m, seen.obstacles
                ),
            );
        }
        if seen.settled {
            self.settled_s = Some(t_s);
            self.log(
                t_s,
                "settled",
                format!("perception marks the new scene settled (+{dt:.3} s)"),
            );
        }
    }

    /// A lookahead verdict: logged; the first after a change marks the prediction.
    fn on_verdict(&mut self, t_s: f64, v: &TwinVerdict, scene: usize) {
        if let Some((kind, blocker, link, by_m)) = v.goal_taken_wire() {
            let reason = InfeasibleReason::from_wire(kind, blocker, link, by_m);
            self.on_goal_taken(t_s, reason, scene);
            return;
        }
        let by = match v.executor() {
            Ok(Executor::Planner) => "planner".to_owned(),
            _ => format!("policy {}", v.policy_id),
        };
        let text = format!(
            "{by} [{}]: task_ok={} safe={} min_distance={:.3} m steps={} plan_approved={} ({} µs)",
            v.phase().map_or("?", PhaseCode::name),
            v.is_task_ok(),
            v.is_safe(),
            v.min_distance_m,
            v.steps,
            v.is_plan_approved(),
            v.lookahead_compute_us
        );
        self.log(t_s, "verdict", text);
        if let Some(mark) = self.acts[scene].on_verdict(t_s, v) {
            self.log_act(t_s, mark);
        }
        // A verification (the goal reached already: the plan is judged, not sent) and a
        // "not learned" verdict move nothing and predict nothing.
        if v.phase() == Ok(PhaseCode::Verification)
            || v.episode_end == shm_schemas::EpisodeEnd::NotLearned as u8
        {
            return;
        }
        if self.change_s.is_some() && v.is_plan_approved() {
            self.approved_after_change = true;
            if self.settled_s.is_some() && self.approved_s.is_none() {
                self.approved_s = Some(t_s);
            }
        }
        if !v.is_plan_approved() {
            self.refused_verdicts[scene] += 1;
        }
        // Zero-shot: a plan is approved on the scene (after it was seen, for a changed world)
        // with a policy already there — the current one or the library's base — before any
        // retraining was asked for it (a retrain request marks the scene not zero-shot).
        let seen = self.change_s.is_none() || self.detect_s.is_some();
        let executor = v.executor().unwrap_or_default();
        if seen && v.is_plan_approved() && !self.moved_by[scene].contains(&executor) {
            self.moved_by[scene].push(executor);
        }
        // The planner's path is not the policy solving the world.
        if seen
            && v.is_plan_approved()
            && executor != Executor::Planner
            && self.zero_shot[scene].is_none()
        {
            self.zero_shot[scene] = Some(true);
        }
        if self.detect_s.is_some() && self.verdict_s.is_none() {
            self.verdict_s = Some(t_s);
            if !v.is_safe() && !self.moved_since_change && self.cfg.lookahead {
                self.predicted_before_motion = true;
                self.log(
                    t_s,
                    "collision_predicted",
                    "the lookahead predicts a collision; the arm has not moved".into(),
                );
            }
        } else if self.verdict_s.is_some()
            && !v.is_safe()
            && !self.moved_since_change
            && self.cfg.lookahead
        {
            self.predicted_before_motion = true;
        }
    }

    /// rt-core said a box has taken the goal (its verdict, on the frame that showed it):
    /// logged as `goal_taken` (`infeasible: <reason>`) and kept for `summary.json`; final (the
    /// scene is over, the arm held; the act ends `infeasible: <reason>`) unless the scene's
    /// boxes still move, as for the learner's answer — a box that leaves makes the goal live
    /// again.
    fn on_goal_taken(&mut self, t_s: f64, reason: Option<InfeasibleReason>, scene: usize) {
        let t_in_scene_s = t_s - self.scene_since_s;
        let words = self.reason_words(t_s, scene, reason, "rt-core found");
        let detail = format!("infeasible: {words}");
        self.goal_taken
            .push(format!("scene {scene} (+{t_in_scene_s:.2} s): {detail}"));
        self.log(t_s, "goal_taken", detail);
        if self.infeasible[scene].is_none()
            && self
                .words_if_final(t_s, scene, reason, "rt-core found")
                .is_some()
        {
            self.infeasible[scene] = Some(words);
        }
    }

    /// `reason` in words, its box described where it was at `t_s` (a moving box's place on
    /// its path, not where the scene file starts it).
    fn reason_words(
        &self,
        t_s: f64,
        scene: usize,
        reason: Option<InfeasibleReason>,
        who: &str,
    ) -> String {
        let t_in_scene_s = t_s - self.scene_since_s;
        let boxes = self
            .cfg
            .world
            .get(scene)
            .and_then(|(_, file)| twin::Scene::from_file(&file.at(t_in_scene_s)).ok())
            .map(|s| s.obstacles)
            .unwrap_or_default();
        reason.map_or_else(
            || format!("{who} no safe way (reason not given)"),
            |r| r.display_with(&boxes).to_string(),
        )
    }

    /// `reason` in words when it is final for `scene` at `t_s`: a box still on its way (or
    /// standing for a while before it moves on) may take a goal only for now, so nothing is
    /// final while the scene's boxes still move (rt-core plans again once they rest).
    fn words_if_final(
        &self,
        t_s: f64,
        scene: usize,
        reason: Option<InfeasibleReason>,
        who: &str,
    ) -> Option<String> {
        let t_in_scene_s = t_s - self.scene_since_s;
        let last_motion_s = self.cfg.world.get(scene).map_or(0.0, |(_, file)| {
            file.obstacles
                .iter()
                .filter_map(|b| b.path.keyframes().last().map(|k| k.at_s))
                .fold(0.0, f64::max)
        });
        (t_in_scene_s >= last_motion_s).then(|| self.reason_words(t_s, scene, reason, who))
    }

    /// A retrain request: logged; the first after a change is timed.
    fn on_retrain_request(&mut self, t_s: f64, r: &RetrainRequest, scene: usize) {
        if !self.requests[scene].contains(&r.request_id) {
            self.requests[scene].push(r.request_id);
        }
        if let Some(mark) = self.acts[scene].on_request(t_s, r) {
            self.log_act(t_s, mark);
        }
        if self.request_s.is_none() && self.change_s.is_some() {
            self.request_s = Some(t_s);
        }
        if self.zero_shot[scene].is_none() {
            self.zero_shot[scene] = Some(false);
        }
        self.log(
            t_s,
            "retrain_request",
            format!(
                "request {} for policy {} ({} obstacle(s))",
                r.request_id, r.failed_policy_id, r.obstacle_count
            ),
        );
    }

    /// Retraining progress: logged at most once a second, and when it ends.
    fn on_progress(&mut self, t_s: f64, p: &RetrainProgress, scene: usize) {
        if !self.requests[scene].contains(&p.request_id) {
            self.stale_progress[scene] += 1;
            if self.stale_progress[scene] == 1 {
                self.log(
                    t_s,
                    "stale_progress",
                    format!(
                        "retraining progress for request {}, which scene {scene} did not make: \
                         ignored (a late answer to an earlier scene's request)",
                        p.request_id
                    ),
                );
            }
            return;
        }
        let phase = RetrainPhase::try_from(p.phase).ok();
        if phase == Some(RetrainPhase::BudgetExhausted) {
            self.budgets_exhausted[scene] += 1;
        }
        if phase == Some(RetrainPhase::Infeasible) {
            self.acts[scene].on_unpublished_answer(t_s);
        }
        if phase == Some(RetrainPhase::Infeasible) && self.infeasible[scene].is_none() {
            let reason = InfeasibleReason::from_wire(
                p.infeasible_kind,
                p.infeasible_blocker,
                p.infeasible_link,
                p.infeasible_by_m,
            );
            let wall_time_s = p.wall_time_s;
            let Some(words) = self.words_if_final(t_s, scene, reason, "the learner found") else {
                self.log(
                    t_s,
                    "infeasible_for_now",
                    format!(
                        "no safe way while the boxes move (after {wall_time_s:.2} s); waiting \
                         for them to come to rest"
                    ),
                );
                return;
            };
            self.log(
                t_s,
                "infeasible",
                format!("no safe way found: {words} (after {wall_time_s:.2} s)"),
            );
            self.infeasible[scene] = Some(words);
            return;
        }
        if matches!(
            phase,
            Some(RetrainPhase::Published | RetrainPhase::BudgetExhausted)
        ) && let Some(mark) = self.acts[scene].on_published(p.published_policy_id)
        {
            self.log_act(t_s, mark);
        }
        let published = phase == Some(RetrainPhase::Published);
        if published && self.published_s.is_none() && self.request_s.is_some() {
            self.published_s = Some(t_s);
        }
        if published
            || phase == Some(RetrainPhase::BudgetExhausted)
            || t_s - self.last_progress_print_s >= 1.0
        {
            self.last_progress_print_s = t_s;
            self.log(
                t_s,
                "retrain_progress",
                format!(
                    "{:?}: {} steps, mean return {:.2}, success {:.0} %, {:.1} s",
                    phase.unwrap_or(RetrainPhase::Training),
                    p.steps_done,
                    p.mean_return,
                    p.success_rate * 100.0,
                    p.wall_time_s
                ),
            );
        }
    }

    /// Moves the scenario on: start, the next scene when due and settled, the end.
    fn advance_phase(&mut self, t_s: f64, actions: &mut Vec<Action>) {
        match self.phase {
            Phase::WaitingForSystem => {
                if self.last_state.is_some() {
                    self.phase = Phase::Reaching {
                        scene: 0,
                        since_s: t_s,
                    };
                    self.log(t_s, "start", "system up; scene 0 in force".into());
                }
            }
            Phase::Reaching { scene, since_s } => {
                let last = scene + 1 == self.cfg.world.len();
                // A scene the learner proved infeasible is over: the arm is held, nothing
                // more will come for it.
                // … and the act's loop is closed: a retraining asked for is answered by a
                // policy rt-core accepted, or the scene is not learned (a slow learner
                // cannot end the act on the planner's path).
                let infeasible = self.infeasible[scene].is_some();
                let act = &self.acts[scene];
                let reached = !self.cfg.goals_from_action
                    && (self.goals_reached[scene] || infeasible || act.not_learned.is_some())
                    && act.loop_closed(infeasible);
                let timed_out = t_s - since_s > self.cfg.phase_timeout_s;
                if timed_out && !reached && !self.cfg.goals_from_action {
                    self.log(
                        t_s,
                        "timeout",
                        format!(
                            "goal {scene} not reached within {:.0} s",
                            self.cfg.phase_timeout_s
                        ),
                    );
                }
                if last && (reached || timed_out) {
                    self.phase = Phase::Done;
                    actions.push(Action::Finish);
                } else if !last {
                    let at_home = self.cfg.home_q_rad.is_none_or(|h| {
                        self.last_state.is_some_and(|s| {
                            max_joint_gap_rad(&h, &s.joints_rad) <= HOME_TOLERANCE_RAD
                        })
                    });
                    let settled = at_home
                        && self
                            .still_since_s
                            .is_some_and(|s| t_s - s >= self.cfg.settle_s);
                    let due = t_s >= self.cfg.world[scene + 1].0;
                    if due && ((reached && settled) || timed_out) {
                        let next = scene + 1;
                        self.phase = Phase::Reaching {
                            scene: next,
                            since_s: t_s,
                        };
                        self.change_s = Some(t_s);
                        self.joints_at_change = self.last_state.map(|s| s.joints_rad);
                        self.moved_since_change = false;
                        (
                            self.detect_s,
                            self.settled_s,
                            self.approved_s,
                            self.verdict_s,
                            self.request_s,
                            self.published_s,
                            self.motion_s,
                        ) = (None, None, None, None, None, None, None);
                        let name = self.cfg.world[next].1.name.clone();
                        self.log(
                            t_s,
                            "world_change",
                            format!(
                                "world changes to scene {next} ({name}): tallest obstacle {:.2} m",
                                Self::tallest(&self.cfg.world[next].1)
                            ),
                        );
                        self.schedule_box_motions(t_s, next);
                        self.scene_since_s = t_s;
                        actions.push(Action::SwitchScene(next));
                    }
                }
            }
            Phase::Done => {}
        }
    }

    fn on_state(&mut self, t_s: f64, s: &RobotState, scene: usize) {
        let tcp = tcp_of(s);
        if self
            .path
            .last()
            .is_none_or(|p| (Vector3::from(p.tcp_m) - tcp).norm() > 0.001)
        {
            self.path.push(PathSample {
                t_s,
                tcp_m: s.tcp_m,
                scene,
            });
        }
        let moving = self.last_state.is_some_and(|prev| {
            prev.joints_rad
                .iter()
                .zip(s.joints_rad.iter())
                .any(|(a, b)| (a - b).abs() > 1e-4)
        });
        self.separation.push(SeparationSample {
            t_s,
            separation_m: separation_m(
                &s.joints_rad,
                &self.cfg.world[scene].1,
                t_s - self.scene_since_s,
            ),
            moving,
        });
        if moving {
            self.still_since_s = None;
        } else if self.still_since_s.is_none() {
            self.still_since_s = Some(t_s);
        }
        self.watch_pause(t_s, s, moving, scene);
        if let Some(q0) = self.joints_at_change
            && !self.moved_since_change
            && q0
                .iter()
                .zip(s.joints_rad.iter())
                .any(|(a, b)| (a - b).abs() > 2e-3)
        {
            self.moved_since_change = true;
            self.motion_s = Some(t_s);
            let dt = t_s - self.change_s.unwrap_or(t_s);
            self.log(
                t_s,
                "motion",
                format!("the arm moves in the new scene (+{dt:.3} s)"),
            );
        }
        // Id 0 is no policy: none yet, or the planner fallback's path. A swap is a policy
        // taking over from another policy, whatever ran in between: the start policy's
        // first plan is not one, and neither is the planner taking over (old → 0) or
        // handing back to the same policy.
        if s.active_policy_id != 0 && self.active_policy != Some(s.active_policy_id) {
            if self.active_policy.is_some() {
                self.policy_swaps += 1;
                if self.published_s.is_none() && self.request_s.is_some() {
                    self.published_s = Some(t_s);
                }
                self.log(
                    t_s,
                    "policy_swap",
                    format!("policy {} now active", s.active_policy_id),
                );
            }
            self.active_policy = Some(s.active_policy_id);
        }
        if s.p99_compute_us.is_finite() && s.p99_compute_us > 0.0 {
            self.p99_us = Some(f64::from(s.p99_compute_us));
        }
        let to_goal_m = (tcp - self.target(scene)).norm();
        self.closest_m[scene] = self.closest_m[scene].min(to_goal_m);
        if !self.goals_reached[scene] && to_goal_m <= self.cfg.goal_tolerance_m {
            self.goals_reached[scene] = true;
            self.acts[scene].change_to_goal_s = Some(t_s - self.scene_since_s);
            self.log(
                t_s,
                "goal_reached",
                format!(
                    "goal {scene} reached (TCP within {:.3} m)",
                    self.cfg.goal_tolerance_m
                ),
            );
        }
        self.last_state = Some(*s);
    }

    /// Marks the arm stopping for an obstacle (`paused`) and moving on again (`resumed`).
    /// rt-core reports a plan its twin revoked and a command its shield refused alike, as a
    /// controlled stop with [`StopReason::ShieldViolation`]; the pause ends when the arm is
    /// out of the stop and its joints move.
    fn watch_pause(&mut self, t_s: f64, s: &RobotState, moving: bool, scene: usize) {
        let for_obstacle = s.is_stopped() && s.stop_reason() == Ok(StopReason::ShieldViolation);
        match self.paused_since_s {
            None if for_obstacle => {
                self.paused_since_s = Some(t_s);
                self.pauses[scene] += 1;
                let after = self
                    .change_s
                    .map_or(String::new(), |c| format!(" (+{:.2} s)", t_s - c));
                self.log(
                    t_s,
                    "paused",
                    format!(
                        "the arm stops for an obstacle{after}: shield_violation (the twin revoked \
                         the plan or the shield refused a command), TCP at ({:.3}, {:.3}, {:.3}) m",
                        s.tcp_m[0], s.tcp_m[1], s.tcp_m[2]
                    ),
                );
            }
            Some(since_s) if !s.is_stopped() && moving => {
                self.paused_since_s = None;
                let pause_s = t_s - since_s;
                self.longest_pause_s =
                    Some(self.longest_pause_s.map_or(pause_s, |l| l.max(pause_s)));
                self.log(
                    t_s,
                    "resumed",
                    format!("the arm moves on after a {pause_s:.2} s pause"),
                );
            }
            _ => {}
        }
    }

    /// Schedules the timeline marks of scene `scene`'s moving boxes, put in force at `t_s`:
    /// `obstacle_moves` where a box sets off, `obstacle_stops` where it comes to rest.
    fn schedule_box_motions(&mut self, t_s: f64, scene: usize) {
        let mut marks = Vec::new();
        for (i, b) in self.cfg.world[scene].1.obstacles.iter().enumerate() {
            let mut was_moving = false;
            for w in b.path.keyframes().windows(2) {
                let moving = w[0].center_m != w[1].center_m;
                if moving && !was_moving {
                    marks.push(box_mark(t_s, i, w[0], "obstacle_moves", "sets off from"));
                }
                if !moving && was_moving {
                    marks.push(box_mark(t_s, i, w[0], "obstacle_stops", "comes to rest at"));
                }
                was_moving = moving;
            }
            if was_moving && let Some(last) = b.path.keyframes().last() {
                marks.push(box_mark(
                    t_s,
                    i,
                    *last,
                    "obstacle_stops",
                    "comes to rest at",
                ));
            }
        }
        marks.sort_by(|a, b| a.0.total_cmp(&b.0));
        self.box_events = marks;
    }

    /// Logs the box motions due by `t_s`, at the times they happen.
    fn mark_box_motions(&mut self, t_s: f64) {
        let due = self.box_events.iter().take_while(|e| e.0 <= t_s).count();
        let marks: Vec<_> = self.box_events.drain(..due).collect();
        for (at_s, kind, detail) in marks {
            self.log(at_s, kind, detail);
        }
    }

    /// Why scene `i`'s goal was not reached, as far as the director saw it.
    fn not_reached_cause(&self, i: usize) -> String {
        let exhausted = self.budgets_exhausted[i];
        let refused = self.refused_verdicts[i];
        if exhausted > 0 {
            format!(
                "the retraining budget ran out {exhausted} time(s) without a policy the twin \
                 passes ({refused} plan(s) refused by the lookahead); the arm was held"
            )
        } else if refused > 0 {
            format!(
                "the lookahead refused {refused} plan(s) and no retrained policy passed in time; \
                 the arm was held"
            )
        } else if self.zero_shot[i] == Some(true) {
            format!(
                "a plan was approved but the arm came only within {:.1} mm of the goal \
                 (tolerance {:.1} mm; a plan the cycle's shield refused, or the twin's goal \
                 off the real one: see `plan rejected` in logs/rt-core.log)",
                1000.0 * self.closest_m[i],
                1000.0 * self.cfg.goal_tolerance_m
            )
        } else {
            "no verdict on the scene in time (perception or the twin did not see it settle)"
                .to_owned()
        }
    }

    /// A timeline line for what a verdict or request meant for the act.
    fn log_act(&mut self, t_s: f64, mark: ActMark) {
        let (kind, detail) = match mark {
            ActMark::Accepted(id) => (
                "policy_accepted",
                format!("rt-core accepts retrained policy {id} in this scene"),
            ),
            ActMark::Refused(words) => (
                "retraining_refused",
                format!("rt-core refuses the retrained {words}"),
            ),
            ActMark::NotLearned(words) => ("not_learned", format!("scene not learned: {words}")),
        };
        self.log(t_s, kind, detail);
    }

    /// Every act so far, scene by scene.
    fn act_summaries(&self) -> Vec<ActSummary> {
        self.acts
            .iter()
            .enumerate()
            .take(self.scene_index() + 1)
            .map(|(i, a)| ActSummary {
                scene: i,
                name: self.cfg.world[i].1.name.clone(),
                goal_reached: self.goals_reached[i],
                change_to_goal_s: a.change_to_goal_s,
                retrain_requests: a.requests.len(),
                policies_published: a.published.len(),
                policies_accepted: a.accepted.len(),
                retrainings_refused: a.refused.clone(),
                executor: executor_words(&self.moved_by[i]),
                not_learned: a.not_learned.clone(),
                infeasible: self.infeasible[i].clone(),
            })
            .collect()
    }

    /// The summary of the run so far (collisions and p99.9 come from outside).
    pub fn summary(
        &self,
        collisions: u64,
        cycle_p999_us: Option<f64>,
        restarts: u64,
        seed: u64,
    ) -> Summary {
        let since = |t: Option<f64>| t.zip(self.change_s).map(|(t, c)| t - c);
        let mut notes = Vec::new();
        let mut outcome = Outcome::Reached;
        let mut outcome_reason = String::new();
        for (i, r) in self.goals_reached.iter().enumerate() {
            if let Some(words) = &self.acts[i].not_learned {
                notes.push(format!("scene {i}: not learned: {words}"));
                if !*r && outcome == Outcome::Reached {
                    outcome = Outcome::NotLearned;
                    outcome_reason = format!("scene {i}: not learned: {words}");
                }
            }
            if *r {
                continue;
            }
            if let Some(words) = &self.infeasible[i] {
                notes.push(format!(
                    "scene {i}: no safe way found: {words}; the arm was held"
                ));
                if outcome == Outcome::Reached {
                    outcome = Outcome::Infeasible;
                    outcome_reason = format!("scene {i}: {words}");
                }
                continue;
            }
            let cause = self.not_reached_cause(i);
            notes.push(format!("goal of scene {i} was not reached: {cause}"));
            if outcome != Outcome::NotLearned {
                outcome = Outcome::NotLearned;
                outcome_reason = format!("scene {i}: {cause}");
            }
        }
        if self.approved_after_change && !self.moved_since_change {
            notes.push(
                "a plan was approved after the world change but the arm never moved: the cycle \
                 refused it (see `plan rejected` in logs/rt-core.log)"
                    .to_owned(),
            );
        }
        Summary {
            goal_reached: self.goals_reached.last().copied().unwrap_or(false),
            outcome,
            outcome_reason,
            zero_shot: self.zero_shot.last().copied().flatten(),
            executor: self
                .moved_by
                .last()
                .map_or(String::new(), |m| executor_words(m)),
            acts: self.act_summaries(),
            planner_fallback: false,
            collisions,
            collision_predicted_before_motion: self.predicted_before_motion,
            policy_swaps: self.policy_swaps,
            pauses: self.pauses.iter().map(|&p| u64::from(p)).sum(),
            longest_pause_s: self.longest_pause_s,
            min_separation_moving_m: self.separation.min_moving_m(),
            min_separation_at_rest_m: self.separation.min_at_rest_m(),
            world_change_to_detection_s: since(self.detect_s),
            world_change_to_settled_s: since(self.settled_s),
            world_change_to_approval_s: since(self.approved_s),
            world_change_to_verdict_s: since(self.verdict_s),
            retrain_s: self.request_s.zip(self.published_s).map(|(a, b)| b - a),
            world_change_to_motion_s: since(self.motion_s),
            cycle_p99_us: self.p99_us,
            cycle_p999_us,
            rt_core_realtime: None,
            reaction: None,
            lookahead: self.cfg.lookahead,
            detector: String::new(),
            goal_source: String::new(),
            seed,
            restarts,
            arm_rejected_commands: None,
            remote_learner: None,
            goal_taken: self.goal_taken.clone(),
            notes,
        }
    }
}

/// What moved the arm, in order ("planner, then policy").
fn executor_words(moved_by: &[Executor]) -> String {
    moved_by
        .iter()
        .map(|e| match e {
            Executor::Planner => "planner",
            _ => "policy",
        })
        .collect::<Vec<_>>()
        .join(", then ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::EpisodeEnd;
    use shm_schemas::scene_file::{BoxSpec, GoalSpec, TableSpec};

    fn scene(goal: [f64; 3], h: f64) -> SceneFile {
        SceneFile {
            name: format!("h{h}"),
            table: TableSpec::default(),
            goal: GoalSpec {
                center_m: goal,
                size_m: 0.05,
            },
            obstacles: vec![BoxSpec {
                center_m: [0.35, 0.0, h / 2.0],
                size_m: [0.06, 0.06, h],
                path: Default::default(),
            }],
        }
    }

    fn state(tcp: [f64; 3], q0: f64, policy: u64) -> RobotState {
        RobotState {
            tcp_m: tcp,
            joints_rad: [q0, 0.0, 0.0, 0.0, 0.0],
            active_policy_id: policy,
            p99_compute_us: 12.0,
            ..RobotState::default()
        }
    }

    fn obs_state(s: RobotState) -> Observations {
        Observations {
            states: vec![s],
            ..Observations::default()
        }
    }

    /// The small box's scene, then the demo's goal with one box of height `h` moving along
    /// `path` (time in the scene s, centre m); no settle time.
    fn moving_world(h: f64, path: &[(f64, [f64; 3])]) -> ScenarioConfig {
        use shm_schemas::scene_file::BoxPath;
        let mut moving = scene([0.3, 0.25, 0.025], h);
        let keyframes: Vec<Keyframe> = path
            .iter()
            .map(|&(at_s, center_m)| Keyframe { at_s, center_m })
            .collect();
        moving.obstacles[0].path = BoxPath::new(&keyframes).unwrap();
        ScenarioConfig {
            world: vec![(0.0, scene([0.4, 0.2, 0.025], 0.06)), (0.0, moving)],
            goal_tolerance_m: 0.02,
            goal_hover_m: 0.05,
            phase_timeout_s: 60.0,
            settle_s: 0.0,
            lookahead: true,
            home_q_rad: None,
            goals_from_action: false,
        }
    }

    /// A director on `cfg` whose arm rests at goal 0, switched to scene 1 at 0.1 s.
    fn switched_to_scene_1(cfg: ScenarioConfig) -> Director {
        let mut d = Director::new(cfg);
        d.step(0.0, &obs_state(state([0.4, 0.2, 0.1], 0.0, 1)));
        assert_eq!(
            d.step(0.1, &obs_state(state([0.4, 0.2, 0.1], 0.0, 1))),
            vec![Action::SwitchScene(1)]
        );
        d
    }

    #[test]
    fn measures_the_self_improving_loop_from_the_outside() {
        let cfg = ScenarioConfig {
            world: vec![
                (0.0, scene([0.4, 0.2, 0.025], 0.06)),
                (5.0, scene([0.4, -0.2, 0.025], 0.35)),
            ],
            goal_tolerance_m: 0.02,
            goal_hover_m: 0.05,
            phase_timeout_s: 60.0,
            settle_s: 0.5,
            lookahead: true,
            home_q_rad: None,
            goals_from_action: false,
        };
        let g0 = [0.4, 0.2, 0.1];
        let g1 = [0.4, -0.2, 0.1];
        let mut d = Director::new(cfg);
        assert!(
            d.step(0.0, &obs_state(state([0.3, 0.0, 0.25], 0.0, 1)))
                .is_empty()
        );
        d.step(1.0, &obs_state(state([0.35, 0.1, 0.2], 0.1, 1)));
        d.step(2.0, &obs_state(state(g0, 0.2, 1)));
        // Reached but the switch is due only at 5 s, and the arm must settle.
        assert!(d.step(3.0, &obs_state(state(g0, 0.2, 1))).is_empty());
        let actions = d.step(5.1, &obs_state(state(g0, 0.2, 1)));
        assert_eq!(actions, vec![Action::SwitchScene(1)]);
        // Detection of the tall box.
        let seen = Observations {
            scene: Some(SeenScene {
                goal_m: Some([0.4, -0.2, 0.025]),
                tallest_obstacle_m: 0.35,
                obstacles: 1,
                sequence: 9,
                settled: false,
            }),
            ..Observations::default()
        };
        d.step(5.2, &seen);
        let mut settled = seen.scene.expect("seen");
        settled.settled = true;
        settled.sequence = 15;
        d.step(
            5.205,
            &Observations {
                scene: Some(settled),
                ..Observations::default()
            },
        );
        let mut v = TwinVerdict {
            policy_id: 1,
            episode_end: EpisodeEnd::Collision as u8,
            ..TwinVerdict::default()
        };
        v.set_flags(false, false, false);
        d.step(
            5.21,
            &Observations {
                verdicts: vec![v],
                retrain_requests: vec![RetrainRequest::default()],
                ..Observations::default()
            },
        );
        // The learner publishes policy 2 and rt-core approves a plan of it: the act's loop
        // is closed (issue 40 item 2: the act ends only then).
        let mut approved = TwinVerdict {
            policy_id: 2,
            episode_end: EpisodeEnd::Success as u8,
            ..TwinVerdict::default()
        };
        approved.set_flags(true, true, true);
        d.step(
            7.0,
            &Observations {
                progress: vec![RetrainProgress {
                    phase: RetrainPhase::Published as u8,
                    published_policy_id: 2,
                    ..RetrainProgress::default()
                }],
                states: vec![state(g0, 0.2, 2)],
                ..Observations::default()
            },
        );
        d.step(
            7.1,
            &Observations {
                verdicts: vec![approved],
                ..Observations::default()
            },
        );
        d.step(7.5, &obs_state(state([0.38, 0.0, 0.3], 0.3, 2)));
        let actions = d.step(9.0, &obs_state(state(g1, 0.5, 2)));
        assert_eq!(actions, vec![Action::Finish]);
        let s = d.summary(0, Some(30.0), 0, 7);
        assert!(s.goal_reached);
        assert!(s.collision_predicted_before_motion);
        assert_eq!(s.policy_swaps, 1);
        assert!((s.world_change_to_detection_s.unwrap() - 0.1).abs() < 1e-9);
        assert!((s.world_change_to_settled_s.unwrap() - 0.105).abs() < 1e-9);
        // The verdict at 5.21 s refused the plan (a collision predicted): no approval yet
        // when the retrained policy is published.
        assert!(
            s.world_change_to_approval_s.is_none_or(|a| a > 0.11),
            "{s:?}"
        );
        assert!((s.world_change_to_verdict_s.unwrap() - 0.11).abs() < 1e-9);
        assert!((s.retrain_s.unwrap() - (7.0 - 5.21)).abs() < 1e-9);
        assert!((s.world_change_to_motion_s.unwrap() - 2.4).abs() < 1e-9);
        assert_eq!(s.cycle_p99_us, Some(12.0));
        let kinds: Vec<&str> = d.events().iter().map(|e| e.kind).collect();
        for k in [
            "start",
            "goal_reached",
            "world_change",
            "detection",
            "verdict",
            "collision_predicted",
            "retrain_request",
            "policy_swap",
            "motion",
        ] {
            assert!(kinds.contains(&k), "timeline lacks {k}: {kinds:?}");
        }
        assert!(d.path().iter().any(|p| p.scene == 1));
    }

    #[test]
    fn the_planner_taking_over_is_not_a_swap_and_the_retrained_policy_after_it_is() {
        let mut d = switched_to_scene_1(moving_world(0.2, &[(0.0, [0.3, 0.25, 0.1])]));
        // Policy 1 → the planner's path (id 0) → back to policy 1: no swap.
        d.step(0.5, &obs_state(state([0.4, 0.2, 0.1], 0.0, 0)));
        d.step(1.0, &obs_state(state([0.4, 0.2, 0.1], 0.0, 1)));
        assert_eq!(d.summary(0, None, 0, 1).policy_swaps, 0);
        // The planner again, then the retrained policy 2: one swap, logged when 2 runs.
        d.step(1.5, &obs_state(state([0.4, 0.2, 0.1], 0.0, 0)));
        d.step(2.0, &obs_state(state([0.4, 0.2, 0.1], 0.0, 2)));
        assert_eq!(d.summary(0, None, 0, 1).policy_swaps, 1);
        let swaps: Vec<&str> = d
            .events()
            .iter()
            .filter(|e| e.kind == "policy_swap")
            .map(|e| e.detail.as_str())
            .collect();
        assert_eq!(swaps, vec!["policy 2 now active"]);
    }

    #[test]
    fn a_box_in_the_way_shows_as_a_pause_and_the_continuation() {
        let mut d = switched_to_scene_1(moving_world(
            0.2,
            &[
                (1.0, [0.05, 0.2, 0.1]),
                (2.0, [0.3, 0.14, 0.1]),
                (3.0, [0.3, 0.14, 0.1]),
                (4.0, [0.55, 0.08, 0.1]),
            ],
        ));
        d.step(0.5, &obs_state(state([0.35, 0.1, 0.2], 0.1, 1)));
        let stopped = |q0: f64| RobotState {
            controlled_stop: 1,
            stop_reason: StopReason::ShieldViolation as u8,
            ..state([0.33, 0.15, 0.18], q0, 1)
        };
        d.step(1.5, &obs_state(stopped(0.15)));
        d.step(2.0, &obs_state(stopped(0.15)));
        // Out of the stop but not yet moving: still paused.
        d.step(3.0, &obs_state(state([0.33, 0.15, 0.18], 0.15, 1)));
        d.step(3.5, &obs_state(state([0.32, 0.2, 0.15], 0.2, 1)));
        d.step(4.5, &obs_state(state([0.3, 0.25, 0.1], 0.25, 1)));
        let kinds: Vec<&str> = d.events().iter().map(|e| e.kind).collect();
        let at = |k: &str| kinds.iter().position(|x| *x == k).unwrap();
        assert!(
            at("obstacle_moves") < at("paused")
                && at("paused") < at("obstacle_stops")
                && at("obstacle_stops") < at("resumed")
                && at("resumed") < kinds.iter().rposition(|x| *x == "goal_reached").unwrap(),
            "{kinds:?}"
        );
        assert_eq!(kinds.iter().filter(|k| **k == "obstacle_moves").count(), 2);
        assert_eq!(kinds.iter().filter(|k| **k == "obstacle_stops").count(), 2);
        let moves = &d.events()[at("obstacle_moves")];
        assert!((moves.t_s - 1.1).abs() < 1e-9, "{moves:?}");
        let s = d.summary(0, None, 0, 0);
        assert_eq!(s.pauses, 1);
        assert!((s.longest_pause_s.unwrap() - 2.0).abs() < 1e-9, "{s:?}");
        assert!(s.goal_reached);
    }

    /// Issue 30 item 7: a late answer to the first scene's request (here: "infeasible" and
    /// "published") must neither end nor relabel the second scene; only progress for the
    /// second scene's own request counts. Before the fix the stale "infeasible" marked scene
    /// 1 infeasible and the stale "published" timed its retraining.
    #[test]
    fn progress_for_an_earlier_scenes_request_neither_ends_nor_relabels_the_current_scene() {
        let cfg = ScenarioConfig {
            world: vec![
                (0.0, scene([0.4, 0.2, 0.025], 0.06)),
                (0.0, scene([0.4, -0.2, 0.025], 0.35)),
            ],
            goal_tolerance_m: 0.02,
            goal_hover_m: 0.05,
            phase_timeout_s: 60.0,
            settle_s: 0.0,
            lookahead: true,
            home_q_rad: None,
            goals_from_action: false,
        };
        let mut d = Director::new(cfg);
        // Scene 0 asked for retraining (request 7) before its goal was reached; its answer,
        // policy 5, is published and accepted (the act's loop closed).
        d.step(
            0.0,
            &Observations {
                retrain_requests: vec![RetrainRequest {
                    request_id: 7,
                    ..RetrainRequest::default()
                }],
                progress: vec![RetrainProgress {
                    request_id: 7,
                    phase: RetrainPhase::Published as u8,
                    published_policy_id: 5,
                    ..RetrainProgress::default()
                }],
                ..obs_state(state([0.4, 0.2, 0.1], 0.0, 1))
            },
        );
        let mut accepted = TwinVerdict {
            policy_id: 5,
            ..TwinVerdict::default()
        };
        accepted.set_flags(true, true, true);
        assert_eq!(
            d.step(
                0.1,
                &Observations {
                    verdicts: vec![accepted],
                    ..obs_state(state([0.4, 0.2, 0.1], 0.0, 1))
                }
            ),
            vec![Action::SwitchScene(1)]
        );
        // Scene 1 asks (request 8); request 7's late answers arrive.
        d.step(
            0.2,
            &Observations {
                retrain_requests: vec![RetrainRequest {
                    request_id: 8,
                    ..RetrainRequest::default()
                }],
                ..Observations::default()
            },
        );
        let late = |phase: RetrainPhase| RetrainProgress {
            request_id: 7,
            phase: phase as u8,
            ..RetrainProgress::default()
        };
        d.step(
            0.3,
            &Observations {
                progress: vec![
                    late(RetrainPhase::Infeasible),
                    late(RetrainPhase::Published),
                ],
                ..Observations::default()
            },
        );
        let kinds: Vec<&str> = d.events().iter().map(|e| e.kind).collect();
        assert!(!kinds.contains(&"infeasible"), "{kinds:?}");
        assert!(kinds.contains(&"stale_progress"), "{kinds:?}");
        let s = d.summary(0, None, 0, 0);
        assert_eq!(s.retrain_s, None, "{s:?}");
        assert_ne!(s.outcome, Outcome::Infeasible, "{s:?}");
        // Scene 1's own answer counts.
        d.step(
            0.4,
            &Observations {
                progress: vec![RetrainProgress {
                    request_id: 8,
                    phase: RetrainPhase::Infeasible as u8,
                    ..RetrainProgress::default()
                }],
                ..Observations::default()
            },
        );
        let kinds: Vec<&str> = d.events().iter().map(|e| e.kind).collect();
        assert!(kinds.contains(&"infeasible"), "{kinds:?}");
    }

    /// A box that stands on the goal's way for a while makes the goal unreachable only for
    /// now: the learner's "infeasible" while the scene's boxes still move is logged and does
    /// not end the scene (before, the run gave up on a goal the box left a second later);
    /// after the last keyframe it is final as before.
    #[test]
    fn infeasible_while_the_boxes_move_is_not_final() {
        let mut d = switched_to_scene_1(moving_world(
            0.12,
            &[
                (0.5, [0.6, 0.06, 0.06]),
                (1.0, [0.3, 0.19, 0.06]),
                (2.0, [0.3, 0.19, 0.06]),
                (2.5, [0.6, 0.06, 0.06]),
            ],
        ));
        let request = |id: u64| Observations {
            retrain_requests: vec![RetrainRequest {
                request_id: id,
                ..RetrainRequest::default()
            }],
            ..Observations::default()
        };
        let infeasible = |id: u64| Observations {
            progress: vec![RetrainProgress {
                request_id: id,
                phase: RetrainPhase::Infeasible as u8,
                ..RetrainProgress::default()
            }],
            ..Observations::default()
        };
        // 1.5 s into the scene: the box stands on the way.
        d.step(1.6, &request(1));
        d.step(1.61, &infeasible(1));
        let kinds: Vec<&str> = d.events().iter().map(|e| e.kind).collect();
        assert!(kinds.contains(&"infeasible_for_now"), "{kinds:?}");
        assert!(!kinds.contains(&"infeasible"), "{kinds:?}");
        assert!(
            d.step(1.7, &Observations::default()).is_empty(),
            "the scene goes on"
        );
        // After the box's last keyframe an infeasible verdict is final.
        d.step(3.0, &request(2));
        d.step(3.01, &infeasible(2));
        let kinds: Vec<&str> = d.events().iter().map(|e| e.kind).collect();
        assert!(kinds.contains(&"infeasible"), "{kinds:?}");
        assert_eq!(d.summary(0, None, 0, 0).outcome, Outcome::Infeasible);
    }

    /// Issue 42 item 4: rt-core's "a box has taken the goal" verdict is in the timeline and
    /// `summary.json` at once (`infeasible: <reason>`); while the scene's box still moves it
    /// is not final, after its last keyframe it ends the scene infeasible.
    #[test]
    fn rt_core_s_goal_taken_is_in_the_timeline_and_the_summary_at_once() {
        let mut d = switched_to_scene_1(moving_world(
            0.12,
            &[
                (0.5, [0.6, 0.06, 0.06]),
                (1.0, [0.3, 0.19, 0.06]),
                (2.0, [0.3, 0.19, 0.06]),
                (2.5, [0.6, 0.06, 0.06]),
            ],
        ));
        let taken = |verdict_id: u64| Observations {
            verdicts: vec![TwinVerdict {
                verdict_id,
                episode_end: EpisodeEnd::GoalTaken as u8,
                taken_blocker: 0,
                taken_link: twin::LINK_TOOL,
                min_distance_m: -0.045,
                ..TwinVerdict::default()
            }],
            ..Observations::default()
        };
        d.step(1.6, &taken(9));
        let detail = d
            .events()
            .iter()
            .find(|e| e.kind == "goal_taken")
            .map(|e| e.detail.clone())
            .unwrap_or_else(|| panic!("no goal_taken line: {:?}", d.events()));
        assert!(
            detail.starts_with("infeasible: no safe goal posture: box 0 (0.06 × 0.06 × 0.12 m"),
            "{detail}"
        );
        let s = d.summary(0, None, 0, 0);
        assert_eq!(s.goal_taken.len(), 1, "{s:?}");
        assert!(s.goal_taken[0].contains("infeasible: "), "{s:?}");
        assert_ne!(s.outcome, Outcome::Infeasible, "the box still moves: {s:?}");
        assert_eq!(s.acts[1].infeasible, None, "the box still moves: {s:?}");
        d.step(3.0, &taken(10));
        let s = d.summary(0, None, 0, 0);
        assert_eq!(s.outcome, Outcome::Infeasible);
        // The act ends "infeasible: <reason>" (summary.json's acts, report.md's table).
        let row = s.acts[1].markdown_row();
        assert!(
            row.contains("| infeasible: no safe goal posture: box 0 (")
                && !row.contains("infeasible: infeasible"),
            "{row}"
        );
    }

    /// Each world change times its own settled scene: the demo's third act once reported
    /// `world_change_to_settled_s` = −18 s, the second act's settled frame measured from the
    /// third act's change.
    #[test]
    fn the_settled_scene_is_timed_per_world_change() {
        let cfg = ScenarioConfig {
            world: vec![
                (0.0, scene([0.4, 0.2, 0.025], 0.06)),
                (0.0, scene([0.4, -0.2, 0.025], 0.35)),
                (0.0, scene([0.3, 0.2, 0.025], 0.2)),
            ],
            goal_tolerance_m: 0.02,
            goal_hover_m: 0.05,
            phase_timeout_s: 30.0,
            settle_s: 0.0,
            lookahead: false,
            home_q_rad: None,
            goals_from_action: false,
        };
        let seen = |goal: [f32; 3], tallest: f32| Observations {
            scene: Some(SeenScene {
                goal_m: Some(goal),
                tallest_obstacle_m: tallest,
                obstacles: 1,
                sequence: 3,
                settled: true,
            }),
            ..Observations::default()
        };
        let mut d = Director::new(cfg);
        d.step(0.0, &obs_state(state([0.4, 0.2, 0.1], 0.0, 1)));
        assert_eq!(
            d.step(0.1, &obs_state(state([0.4, 0.2, 0.1], 0.0, 1))),
            vec![Action::SwitchScene(1)]
        );
        d.step(0.2, &seen([0.4, -0.2, 0.025], 0.35));
        let first = d.summary(0, None, 0, 0).world_change_to_settled_s.unwrap();
        assert!((first - 0.1).abs() < 1e-9, "{first}");
        // Goal 1 reached and still: the third world comes; nothing of it is settled yet.
        assert_eq!(
            d.step(1.0, &obs_state(state([0.4, -0.2, 0.1], 0.0, 2))),
            vec![Action::SwitchScene(2)]
        );
        assert_eq!(d.summary(0, None, 0, 0).world_change_to_settled_s, None);
        d.step(1.35, &seen([0.3, 0.2, 0.025], 0.2));
        let settled = d.summary(0, None, 0, 0).world_change_to_settled_s.unwrap();
        assert!((settled - 0.35).abs() < 1e-9, "{settled}");
    }

    #[test]
    fn a_blind_run_that_moves_first_is_not_credited_with_a_prediction() {
        let cfg = ScenarioConfig {
            world: vec![
                (0.0, scene([0.4, 0.2, 0.025], 0.06)),
                (0.0, scene([0.4, -0.2, 0.025], 0.35)),
            ],
            goal_tolerance_m: 0.02,
            goal_hover_m: 0.05,
            phase_timeout_s: 3.0,
            settle_s: 0.0,
            lookahead: false,
            home_q_rad: None,
            goals_from_action: false,
        };
        let mut d = Director::new(cfg);
        d.step(0.0, &obs_state(state([0.4, 0.2, 0.1], 0.0, 1)));
        // Goal 0 reached, arm still, scene 1 due at once: the world changes.
        assert_eq!(
            d.step(0.1, &obs_state(state([0.4, 0.2, 0.1], 0.0, 1))),
            vec![Action::SwitchScene(1)]
        );
        d.step(0.3, &obs_state(state([0.38, 0.0, 0.2], 0.3, 1)));
        let seen = Observations {
            scene: Some(SeenScene {
                goal_m: Some([0.4, -0.2, 0.025]),
                tallest_obstacle_m: 0.35,
                obstacles: 1,
                sequence: 3,
                settled: true,
            }),
            ..Observations::default()
        };
        d.step(0.4, &seen);
        let mut v = TwinVerdict {
            episode_end: EpisodeEnd::Collision as u8,
            ..TwinVerdict::default()
        };
        v.set_flags(false, false, false);
        d.step(
            0.5,
            &Observations {
                verdicts: vec![v],
                ..Observations::default()
            },
        );
        assert_eq!(d.step(4.0, &Observations::default()), vec![Action::Finish]);
        let s = d.summary(1, None, 0, 0);
        assert!(!s.collision_predicted_before_motion);
        assert!(!s.goal_reached);
        assert_eq!(s.collisions, 1);
        assert!(s.notes.iter().any(|n| n.contains("scene 1")));
    }
}
