//! The self-improving scenario end to end: [`run_all`] starts the processes under one
//! unique service prefix ([`processes`]), directs the world script against them
//! ([`crate::scenario::Director`]), watches the ground truth of the simulated arm, stops
//! everything in order, and writes the report. The `foresight` binary parses
//! [`crate::args::LaunchArgs`] and calls [`run_all`].

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use rand::SeedableRng;
use shm_schemas::clock::monotonic_now_ns;
use shm_schemas::scene_file::{LiveScene, SceneFile, WorldScript};
use twin::{ObstacleClass, RobotModel, Scene, TaskConfig, TwinEnv};

use crate::args::{LaunchArgs, WorldsChoice};
use crate::observer::Observer;
use crate::processes::{self, Started};
use crate::report::{self, View};
use crate::run_dir::{RunDir, write_atomic};
use crate::runtime_view::RuntimeView;
use crate::scenario::{Action, Director, ScenarioConfig, TimelineEvent};
use crate::sim_link::{sim_control, sim_status};
use crate::supervisor::{ProcessEvent, Supervisor};

/// Runs one scenario, or `--runs N` randomised ones; true when every run met its goal.
pub fn run_all(args: &LaunchArgs) -> Result<bool> {
    args.check_blind_mode()?;
    args.check_real_arm_sensors()?;
    args.check_sim_identity()?;
    processes::check_camera_calibration(&args.camera, args.calibration.as_deref())?;
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop.clone()).context("installing the signal handler")?;
    }
    let task =
        TaskConfig::load(&args.task).with_context(|| format!("loading {}", args.task.display()))?;
    if args.runs == 0 {
        let world = WorldScript::load(&args.world)
            .with_context(|| format!("loading {}", args.world.display()))?;
        let (summary, _) = run_scenario(args, &task, world.steps, &stop)?;
        return Ok(judge(args, &summary));
    }
    let model =
        RobotModel::load(&args.urdf).with_context(|| format!("loading {}", args.urdf.display()))?;
    let env = TwinEnv::new(model, task);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let mut all_ok = true;
    let mut collisions = 0;
    let random = args.worlds == WorldsChoice::Random;
    if random && task.world.is_none() {
        bail!(
            "--worlds random draws from the task's [world] section, and {} has none",
            args.task.display()
        );
    }
    // The unseen worlds come from their own stream, so that `--seed S` gives the worlds
    // `unseen-worlds --seed S` draws (the warm-up scenes use the other stream).
    let mut world_rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let mut rows = Vec::new();
    for i in 0..args.runs {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let small: Scene = env.sample_scene(&mut rng, ObstacleClass::Small);
        let second: Scene = if random {
            env.sample_world(&mut world_rng)
        } else {
            env.sample_scene(&mut rng, ObstacleClass::Large)
        };
        let (mut a, mut b) = (small.to_file(), second.to_file());
        a.name = format!("random-{i}-small");
        b.name = if random {
            format!("world-{i}")
        } else {
            format!("random-{i}-large")
        };
        println!(
            "=== scenario {}/{} (seed {}) ===",
            i + 1,
            args.runs,
            args.seed
        );
        let (summary, run_dir) =
            run_scenario(args, &task, vec![(0.0, a), (5.0, b.clone())], &stop)?;
        collisions += summary.collisions;
        all_ok &= judge(args, &summary);
        if random {
            rows.push(crate::worlds::WorldRun::new(
                i as usize, &b, &summary, run_dir,
            ));
        }
    }
    println!(
        "=== {} scenario(s): {collisions} collision(s) in total ===",
        args.runs
    );
    if random {
        let dir = args.out.join(format!("worlds-seed{}", args.seed));
        let table = crate::worlds::write_benchmark(&dir, args.seed, &rows)
            .with_context(|| format!("writing the worlds benchmark to {}", dir.display()))?;
        println!("{table}");
        println!("worlds benchmark: {}", dir.join("worlds.md").display());
    }
    Ok(all_ok)
}

fn judge(args: &LaunchArgs, s: &report::Summary) -> bool {
    if args.no_lookahead {
        true
    } else if args.worlds == WorldsChoice::Random && args.runs > 0 {
        // An unseen world may be infeasible: holding the arm and saying so is the right
        // answer there.
        s.collisions == 0
            && matches!(
                s.outcome,
                report::Outcome::Reached | report::Outcome::Infeasible
            )
    } else {
        s.goal_reached && s.collisions == 0 && s.outcome == report::Outcome::Reached
    }
}

/// One timeline line (printed and in report.md); a dry run on synthetic data says so in
/// each ([`LaunchArgs::synthetic_data_note`]).
fn event_line(args: &LaunchArgs, e: &TimelineEvent) -> String {
    let line = format!("{:>8.3} s  {:<20} {}", e.t_s, e.kind, e.detail);
    match args.synthetic_data_note() {
        Some(note) => format!("{line}  {note}"),
        None => line,
    }
}

/// One run's folder, live scene file and service prefix.
struct RunSetup {
    run: RunDir,
    prefix: String,
    live: PathBuf,
}

/// Puts `scene` in force now: writes it to the live scene file with the moment it comes
/// into force (`in_force_since_monotonic_ns`, `CLOCK_MONOTONIC`), the origin of its moving
/// boxes' paths for every process that reads the file (the synthetic camera, the simulated
/// arm): [`shm_schemas::scene_file::live`].
fn write_live_scene(live: &Path, scene: &SceneFile) -> std::io::Result<()> {
    let text = LiveScene::new(scene.clone(), monotonic_now_ns()).to_toml_string();
    write_atomic(live, text.as_bytes())
}

/// Creates the run folder and saves the world: every scene, and the one in force in
/// `world/live.toml` (in force from now).
fn set_up_run(args: &LaunchArgs, world: &[(f64, SceneFile)]) -> Result<RunSetup> {
    let run = RunDir::create(&args.out).context("creating the run folder")?;
    let prefix = format!(
        "fs{}_{}",
        std::process::id(),
        run.path
            .file_name()
            .map(|n| n.to_string_lossy().replace('-', ""))
            .unwrap_or_default()
    );
    println!(
        "foresight: run folder {}, service prefix {prefix}",
        run.path.display()
    );
    for (i, (_, scene)) in world.iter().enumerate() {
        let p = run.file(&format!("world/scene_{i}.toml"))?;
        write_atomic(&p, scene.to_toml_string().as_bytes())?;
    }
    let live = run.file("world/live.toml")?;
    write_live_scene(&live, &world[0].1)?;
    Ok(RunSetup { run, prefix, live })
}

/// Subscribes to the run's services (they appear as the processes come up).
fn open_observer(prefix: &str) -> Result<Observer> {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match Observer::open(prefix) {
            Ok(o) => return Ok(o),
            Err(e) if Instant::now() > deadline => {
                return Err(e).context("subscribing to the run's services");
            }
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}

/// Runs one scenario: processes up, the world script directed against them, an orderly
/// stop, the report. Returns the summary and the run folder.
fn run_scenario(
    args: &LaunchArgs,
    task: &TaskConfig,
    world: Vec<(f64, SceneFile)>,
    stop: &Arc<AtomicBool>,
) -> Result<(report::Summary, PathBuf)> {
    let runtime = RuntimeView::load(&args.runtime)
        .with_context(|| format!("loading {}", args.runtime.display()))?;
    let setup = set_up_run(args, &world)?;
    let mut sup = Supervisor::new(&setup.run.file("logs/.keep")?.with_file_name(""));
    let started = processes::start_all(&mut sup, args, &setup.run, &setup.prefix, &setup.live)?;
    let observer = open_observer(&setup.prefix)?;
    let mut record_notes = Vec::new();
    let recording =
        crate::recording::start(args, &setup.run.path, &setup.prefix, &mut record_notes);
    let mut director = Director::new(ScenarioConfig {
        world: world.clone(),
        goal_tolerance_m: task.success.tolerance_m,
        goal_hover_m: task.success.goal_hover_m,
        phase_timeout_s: args.phase_timeout_s,
        settle_s: 1.0,
        lookahead: !args.no_lookahead,
        home_q_rad: runtime.return_home.then_some(task.start.joints_rad),
        goals_from_action: args.goal_source(runtime.goal.source)
            == crate::args::GoalSourceChoice::Action,
    });
    let mut watch = Watch {
        args,
        setup: &setup,
        world: &world,
        started,
        sup: &mut sup,
        notes: args
            .synthetic_data_note()
            .map(str::to_owned)
            .into_iter()
            .collect(),
        extra_events: Vec::new(),
        last_status_s: f64::NEG_INFINITY,
        collisions_seen: 0,
        blind_collided: false,
        recording: recording.as_ref(),
    };
    watch.direct(&mut director, &observer, stop)?;
    let notes = std::mem::take(&mut watch.notes);
    let (mut summary, referee) = finish(args, &setup, started, &mut sup, &director, notes)?;
    summary.goal_source = args.goal_source(runtime.goal.source).name().to_owned();
    // The processes are stopped: the recording holds everything they published.
    crate::recording::stop(recording, &mut summary.notes);
    summary.notes.extend(record_notes);
    write_report(
        &setup.run,
        args,
        &world,
        &director,
        &summary,
        referee.as_ref(),
    )?;
    println!("\n{}", report::summary_json(&summary, referee.as_ref()));
    if let Some(r) = &referee {
        println!("referee: {}", r.describe());
    }
    println!("report: {}", setup.run.path.join("report.md").display());
    let mcap = setup.run.path.join(crate::recording::RUN_MCAP);
    if mcap.exists() {
        println!("recording: {} (ros2 bag info, Foxglove)", mcap.display());
    }
    Ok((summary, setup.run.path.clone()))
}

/// The launcher's watch over a running scenario.
struct Watch<'a> {
    args: &'a LaunchArgs,
    setup: &'a RunSetup,
    world: &'a [(f64, SceneFile)],
    started: Started,
    sup: &'a mut Supervisor,
    notes: Vec<String>,
    extra_events: Vec<TimelineEvent>,
    last_status_s: f64,
    collisions_seen: u64,
    blind_collided: bool,
    /// The run's recording, which also gets the referee's figures.
    recording: Option<&'a recorder::Recorder>,
}

impl Watch<'_> {
    /// Directs the world script until it is done, rt-core exits, a blind run collides, the
    /// user interrupts, or the overall time runs out; prints and saves the timeline.
    fn direct(
        &mut self,
        director: &mut Director,
        observer: &Observer,
        stop: &AtomicBool,
    ) -> Result<()> {
        let t0 = Instant::now();
        let mut timeline = self.setup.run.create_new_file("timeline.jsonl")?;
        let mut printed = 0;
        let overall_timeout =
            Duration::from_secs_f64(self.args.phase_timeout_s * (self.world.len() as f64) + 60.0);
        loop {
            let t_s = t0.elapsed().as_secs_f64();
            if stop.load(Ordering::Relaxed) {
                self.notes.push("interrupted (Ctrl-C)".to_owned());
                break;
            }
            if t0.elapsed() > overall_timeout {
                self.notes.push(format!(
                    "gave up after {:.0} s",
                    overall_timeout.as_secs_f64()
                ));
                break;
            }
            self.poll_processes(t_s);
            if !self.sup.is_running("rt-core") {
                let log = self.setup.run.path.join("logs/rt-core.log");
                self.notes.push(match last_error_line(&log) {
                    Some(line) => format!("rt-core exited: {line}"),
                    None => "rt-core exited".to_owned(),
                });
                break;
            }
            self.check_ground_truth(t_s);
            for a in director.step(t_s, &observer.poll()) {
                self.apply(a)?;
            }
            let mut new: Vec<TimelineEvent> = director.events()[printed..].to_vec();
            printed = director.events().len();
            new.append(&mut self.extra_events);
            for e in &new {
                println!("{}", event_line(self.args, e));
                let _ = writeln!(timeline, "{}", serde_json::to_string(e).unwrap_or_default());
            }
            if director.is_done() || self.blind_collided {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = timeline.flush();
        Ok(())
    }

    /// Process exits and restarts become timeline events.
    fn poll_processes(&mut self, t_s: f64) {
        for ev in self.sup.poll() {
            let detail = match &ev {
                ProcessEvent::Exited {
                    name,
                    status,
                    will_restart,
                } => format!(
                    "{name} exited ({status}){}",
                    if *will_restart { "; restarting" } else { "" }
                ),
                ProcessEvent::Restarted { name, restarts } => {
                    format!("{name} restarted (#{restarts})")
                }
            };
            self.extra_events.push(TimelineEvent {
                t_s,
                kind: "process",
                detail,
            });
        }
    }

    /// Ground truth from the simulated arm, twice a second: a new collision is an event
    /// (and ends a blind run); the referee's figures go to the recording.
    fn check_ground_truth(&mut self, t_s: f64) {
        let Some(sim) = self.started.sim else { return };
        if t_s - self.last_status_s < 0.5 {
            return;
        }
        self.last_status_s = t_s;
        let status = sim_status(sim.control);
        if let (Some(rec), Some(r)) = (
            self.recording,
            status
                .as_ref()
                .and_then(crate::recording::referee_from_status),
        ) {
            rec.referee(r);
        }
        if let Some(n) = status.as_ref().and_then(|v| v["collisions"].as_u64())
            && n > self.collisions_seen
        {
            self.extra_events.push(TimelineEvent {
                t_s,
                kind: "collision",
                detail: format!("xarm-sim reports {n} collision(s)"),
            });
            self.collisions_seen = n;
            if self.args.no_lookahead {
                self.notes
                    .push("the blind run collided: this is what the lookahead prevents".to_owned());
                self.blind_collided = true;
            }
        }
    }

    /// Carries out the director's action: a scene change reaches the camera's world and
    /// the simulated arm's ground truth, both from the same live file (so both count its
    /// moving boxes' time from the same moment).
    fn apply(&mut self, action: Action) -> Result<()> {
        match action {
            Action::SwitchScene(k) => {
                write_live_scene(&self.setup.live, &self.world[k].1)?;
                if let Some(sim) = self.started.sim {
                    let line = format!("scene {}", self.setup.live.display());
                    let reply = sim_control(sim.control, &line)?;
                    if reply != "ok" {
                        bail!("xarm-sim refused the scene change: {reply}");
                    }
                }
            }
            Action::Finish => {}
        }
        Ok(())
    }
}

/// Ground truth from the arm, then an orderly stop (rt-core first), then the summary and
/// the simulated arm's referee figures (`None` on a real arm or when it did not answer).
fn finish(
    args: &LaunchArgs,
    setup: &RunSetup,
    started: Started,
    sup: &mut Supervisor,
    director: &Director,
    mut notes: Vec<String>,
) -> Result<(report::Summary, Option<report::RefereeFigures>)> {
    // rt-core first: it stops the arm under control and puts the controller in its stop
    // state; the simulated arm's status is read after that.
    let rt_status = sup.stop_one("rt-core", crate::processes::RT_CORE_STOP_GRACE);
    if let Some(st) = rt_status.filter(|s| !s.success()) {
        notes.push(format!("rt-core ended with {st}"));
    }
    let sim_status = started.sim.and_then(|sim| {
        let status = sim_status(sim.control);
        if status.is_none() {
            notes.push("could not read xarm-sim's status".into());
        }
        status
    });
    let collisions = sim_status
        .as_ref()
        .and_then(|v| v["collisions"].as_u64())
        .unwrap_or(0);
    let arm_rejected_commands = sim_status
        .as_ref()
        .and_then(|v| v["counters"]["servo_rejected"].as_u64());
    let referee = sim_status
        .as_ref()
        .and_then(report::RefereeFigures::from_sim_status);
    sup.stop_all(Duration::from_secs(5));
    let rt_core_line = read_rt_core_summary(&setup.run.path.join("logs/rt-core.log"));
    let (p99, p999) = rt_core_line.as_ref().map_or((None, None), |v| {
        let c = &v["cycle_compute_us"];
        (c["p99"].as_f64(), c["p999"].as_f64())
    });
    let restarts = ["perception", "learner", "zenoh-relay"]
        .iter()
        .map(|n| u64::from(sup.restarts(n)))
        .sum();
    let mut summary = director.summary(collisions, p999, restarts, args.seed);
    summary.arm_rejected_commands = arm_rejected_commands;
    summary.detector = args.detector.name().to_owned();
    summary.planner_fallback = args.planner_fallback == crate::args::OnOff::On;
    summary.cycle_p99_us = p99.or(summary.cycle_p99_us);
    summary.reaction = rt_core_line.as_ref().and_then(|v| {
        (v["reactions"].as_u64()? > 0).then(|| {
            serde_json::json!({
                "reactions": v["reactions"],
                "capture_to_command_us": v["reaction_capture_to_command_us"],
                "accepted_to_command_us": v["reaction_accepted_to_command_us"],
            })
        })
    });
    summary.rt_core_realtime = rt_core_line.map(|v| {
        serde_json::json!({
            "rt": v["rt"],
            "wakeup_latency_us": v["wakeup_latency_us"],
            "cycles": v["cycles"],
            "missed_deadlines": v["missed_deadlines"],
        })
    });
    summary.notes.extend(notes);
    if args.learner_host {
        let path = setup.run.path.join(crate::processes::RELAY_STATUS);
        match zenoh_relay::status::RelayStatus::read(&path) {
            Ok(st) => {
                let remote = report::RemoteLearner::from_status(&st);
                summary.notes.extend(remote_learner_notes(&remote, &st));
                summary.remote_learner = Some(remote);
            }
            Err(e) => summary
                .notes
                .push(format!("--learner-host: no relay status ({e})")),
        }
    }
    Ok((summary, referee))
}

/// What a person should know about the remote learner: never heard from, requests left
/// unanswered, messages refused.
fn remote_learner_notes(
    remote: &report::RemoteLearner,
    st: &zenoh_relay::status::RelayStatus,
) -> Vec<String> {
    let mut notes = Vec::new();
    if remote.host.is_empty() {
        let via: Vec<&str> = st
            .peers
            .iter()
            .chain(&st.listen)
            .map(String::as_str)
            .collect();
        notes.push(format!(
            "the learner host was never heard from over {}: is `zenoh-relay learner-host` running \
             there with the same --link-name ({}) and the other folder of the same `zenoh-relay \
             keygen` (a session without the link credential is refused), and is its TCP port open?",
            via.join(", "),
            st.link_name
        ));
    }
    for r in st
        .requests
        .iter()
        .filter(|r| r.answered_unix_s.is_none() && !r.superseded)
    {
        notes.push(format!(
            "retrain request {} was sent {} time(s) to the learner host and not answered",
            r.request_id, r.sends
        ));
    }
    if let Some(m) = &st.task_mismatch {
        notes.push(m.clone());
    }
    if remote.rejected > 0 {
        let reasons: Vec<String> = remote
            .rejected_by_reason
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect();
        notes.push(format!(
            "{} message(s) from the learner host were refused ({}); the last: {}",
            remote.rejected,
            reasons.join(", "),
            remote.last_rejection.as_deref().unwrap_or("?")
        ));
        if remote.rejected_by_reason.contains_key("bad_signature")
            || remote.rejected_by_reason.contains_key("replay")
        {
            notes.push(
                "messages not signed by the learner host's key, or replayed, reached the robot \
                 PC's relay and were refused: someone holding the link credential is sending \
                 them, or the two hosts use keys of different `zenoh-relay keygen` runs"
                    .to_owned(),
            );
        }
    }
    notes
}

/// The last `ERROR` line of a process log (why it exited, when it says so), trimmed.
fn last_error_line(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().rev().find(|l| l.contains(" ERROR ")).map(|l| {
        l.split_once(" ERROR ")
            .map_or(l, |(_, rest)| rest)
            .trim()
            .to_owned()
    })
}

/// Cycle compute p99 and p99.9 (µs) from the JSON line `rt-core run` prints at exit.
/// rt-core's one-line JSON summary (the last line of its log that holds
/// `cycle_compute_us`), if it wrote one.
fn read_rt_core_summary(log: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().rev().find_map(|l| {
        let v: serde_json::Value = serde_json::from_str(l.trim()).ok()?;
        v.get("cycle_compute_us")?;
        Some(v)
    })
}

fn write_report(
    run: &RunDir,
    args: &LaunchArgs,
    world: &[(f64, SceneFile)],
    director: &Director,
    summary: &report::Summary,
    referee: Option<&report::RefereeFigures>,
) -> Result<()> {
    report::write_summary(&run.path.join("summary.json"), summary, referee)?;
    report::plot_path(
        &run.path.join("tcp_path_top.png"),
        View::Top,
        director.path(),
        world,
    )?;
    report::plot_path(
        &run.path.join("tcp_path_side.png"),
        View::Side,
        director.path(),
        world,
    )?;
    let mut images = vec![
        ("TCP path, top view", "tcp_path_top.png"),
        ("TCP path, side view", "tcp_path_side.png"),
    ];
    if !director.separation().samples().is_empty() {
        crate::separation::plot_separation(
            &run.path.join("separation.png"),
            director.separation().samples(),
            &director.world_changes_s(),
        )?;
        images.push((
            "Separation of the arm from the boxes over time",
            "separation.png",
        ));
    }
    let mut curves = Vec::new();
    if let Some(csv) = find_csv(&args.checkpoint)
        && let Ok(c) = report::read_reward_curve(&csv)
    {
        curves.push(("pre-training (bundled policy)".to_owned(), c));
    }
    let retrain_dir = run.path.join("retrain");
    if let Some(csv) = find_csv(&retrain_dir)
        && let Ok(c) = report::read_reward_curve(&csv)
    {
        curves.push(("retraining on the new scene".to_owned(), c));
    }
    if !curves.is_empty() {
        report::plot_reward_curves(
            &run.path.join("reward_curves.png"),
            "Reward curves",
            &curves,
        )?;
        images.push(("Reward curves", "reward_curves.png"));
    }
    let timeline: Vec<String> = director
        .events()
        .iter()
        .map(|e| event_line(args, e))
        .collect();
    let mut files = vec![
        ("summary.json", "summary.json"),
        ("verdict timeline (JSONL)", "timeline.jsonl"),
    ];
    if run.path.join(crate::recording::RUN_MCAP).exists() {
        files.push((
            "run recording (MCAP: `ros2 bag info`, Foxglove)",
            crate::recording::RUN_MCAP,
        ));
    }
    files.extend([("process logs", "logs/"), ("world scenes", "world/")]);
    report::write_markdown(
        &run.path.join("report.md"),
        summary,
        referee,
        &timeline,
        &images,
        &files,
    )?;
    Ok(())
}

/// The newest `*.csv` under `dir` (depth ≤ 3).
fn find_csv(dir: &Path) -> Option<PathBuf> {
    fn walk(dir: &Path, depth: u32, best: &mut Option<(std::time::SystemTime, PathBuf)>) {
        let Ok(rd) = std::fs::read_dir(dir) else {
            return;
        };
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() && depth < 3 {
                walk(&p, depth + 1, best);
            } else if p.extension().is_some_and(|x| x == "csv")
                && let Ok(m) = e.metadata().and_then(|m| m.modified())
                && best.as_ref().is_none_or(|(t, _)| m > *t)
            {
                *best = Some((m, p));
            }
        }
    }
    let mut best = None;
    walk(dir, 0, &mut best);
    best.map(|(_, p)| p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use zenoh_relay::status::{PeerStatus, RelayStatus, RequestStatus};

    #[test]
    fn the_report_names_a_silent_learner_host_unanswered_requests_and_a_task_mismatch() {
        let mut st = RelayStatus {
            peers: vec!["tcp/10.0.0.2:7447".into()],
            link_name: "arm-1".into(),
            requests: vec![
                RequestStatus {
                    request_id: 1,
                    sends: 2,
                    superseded: true,
                    ..RequestStatus::default()
                },
                RequestStatus {
                    request_id: 2,
                    sends: 5,
                    ..RequestStatus::default()
                },
            ],
            ..RelayStatus::default()
        };
        let remote = report::RemoteLearner::from_status(&st);
        let notes = remote_learner_notes(&remote, &st).join("\n");
        assert!(
            notes.contains("never heard from over tcp/10.0.0.2:7447"),
            "{notes}"
        );
        assert!(notes.contains("(arm-1)"), "{notes}");
        assert!(notes.contains("request 2 was sent 5 time(s)"), "{notes}");
        assert!(
            !notes.contains("request 1 "),
            "a superseded request is not a fault: {notes}"
        );

        // Heard from, answered, a task mismatch and refusals.
        st.peer = Some(PeerStatus {
            host: "gpu-box".into(),
            connected: true,
            ..PeerStatus::default()
        });
        st.requests[1].submitted_unix_s = 100.0;
        st.requests[1].answered_unix_s = Some(104.5);
        st.requests[1].remote_wall_time_s = Some(4.0);
        st.task_mismatch = Some("the learner host trains for task hash 0x1".into());
        st.rejected.insert("task_mismatch".into(), 3);
        st.last_rejection = Some("retrain request 2 refused".into());
        let remote = report::RemoteLearner::from_status(&st);
        assert_eq!(remote.host, "gpu-box");
        assert_eq!(
            (remote.requests, remote.answered, remote.rejected),
            (2, 1, 3)
        );
        assert_eq!(remote.request_to_answer_s, [4.5]);
        let line = remote.describe();
        assert!(
            line.contains("`gpu-box`")
                && line.contains("request → answer 4.50 s (4.00 s training there)"),
            "{line}"
        );
        let notes = remote_learner_notes(&remote, &st).join("\n");
        assert!(!notes.contains("never heard from"), "{notes}");
        assert!(notes.contains("task hash 0x1"), "{notes}");
        assert!(
            notes.contains("3 message(s) from the learner host were refused (task_mismatch 3)"),
            "{notes}"
        );
        assert!(!notes.contains("signed"), "{notes}");
        // Issue 25 item 1: refusals by the link's authentication are named.
        st.rejected.insert("bad_signature".into(), 2);
        let remote = report::RemoteLearner::from_status(&st);
        let notes = remote_learner_notes(&remote, &st).join("\n");
        assert!(
            notes.contains("bad_signature 2, task_mismatch 3"),
            "{notes}"
        );
        assert!(
            notes.contains("not signed by the learner host's key"),
            "{notes}"
        );
    }

    #[test]
    fn the_live_scene_file_says_when_its_scene_came_into_force() {
        let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/scenes");
        let scene = SceneFile::load(&scenes.join("crossing_box.toml")).unwrap();
        let dir = std::env::temp_dir().join(format!("foresight-live-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let live = dir.join("live.toml");
        let before = monotonic_now_ns();
        write_live_scene(&live, &scene).unwrap();
        let after = monotonic_now_ns();
        let read = LiveScene::load(&live).unwrap();
        assert_eq!(read.scene, scene, "the scene, paths included");
        let since = read.in_force_since_monotonic_ns.unwrap();
        assert!(
            since >= before && since <= after,
            "{before} ≤ {since} ≤ {after}"
        );
        // Every plain scene reader still takes the file.
        assert_eq!(SceneFile::load(&live).unwrap(), scene);
        std::fs::remove_dir_all(&dir).ok();
    }
}
