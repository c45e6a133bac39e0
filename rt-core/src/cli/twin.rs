//! `rt-core twin …`: debugging queries of the digital twin, one JSON object on stdout.
//!
//! - `fk --joints j1,j2,j3,j4,j5` → `{"tcp":[x,y,z],"links":[{"name","pos","quat":[x,y,z,w]}…]}`
//! - `ik --target x,y,z [--from j1,…,j5]` → `{"joints":[…],"reached":bool,"error_m":f}`
//! - `distance --joints j1,…,j5 --box cx,cy,cz,sx,sy,sz` (repeatable) →
//!   `{"distance_m":f,"robot_point":[…],"obstacle_point":[…],"link":"…","colliding":bool}`
//! - `rollout [--scene FILE] [--episodes N] [--seed S]` with the scripted straight-line
//!   policy → `{"episodes":[{"success","safe","return","steps","min_distance_m"}…],"timing":{…}}`
//!
//! Metres and radians in the base frame. Bad arguments print a message on stderr and exit
//! with status 2.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Value, json};
use shm_schemas::cli_bounds::{f32_within, int_within};
use shm_schemas::scene_file::{MAX_OBSTACLES, SceneFile};
use twin::{
    BoxObstacle, DOF, Goal, IkConfig, IkSolver, Joints, N_FRAMES, ObstacleClass, RobotGeometry,
    RobotModel, Scene, TaskConfig, TwinEnv, rollout,
};

/// Twin queries.
#[derive(Debug, Subcommand)]
pub enum TwinCommand {
    /// Forward kinematics: TCP and every link frame.
    Fk(FkArgs),
    /// Inverse kinematics for a TCP position.
    Ik(IkArgs),
    /// Minimum distance between the robot and axis-aligned boxes.
    Distance(DistanceArgs),
    /// Episodes of the task with the scripted straight-line policy.
    Rollout(RolloutArgs),
}

/// Where the model comes from.
#[derive(Debug, Args)]
pub struct ModelArgs {
    /// Robot URDF (default: the bundled assets/xarm5.urdf).
    #[arg(long)]
    urdf: Option<PathBuf>,
}

/// `twin fk`
#[derive(Debug, Args)]
pub struct FkArgs {
    /// Joint angles (rad), comma-separated: j1,j2,j3,j4,j5.
    #[arg(long, value_parser = parse_joints, allow_hyphen_values = true)]
    joints: Joints,
    #[command(flatten)]
    model: ModelArgs,
}

/// `twin ik`
#[derive(Debug, Args)]
pub struct IkArgs {
    /// TCP target (m): x,y,z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    target: [f64; 3],
    /// Start joints (rad), default the home posture.
    #[arg(long, value_parser = parse_joints, allow_hyphen_values = true)]
    from: Option<Joints>,
    /// Iteration budget.
    #[arg(long, default_value_t = 200, value_parser = int_within(1u32, 1_000_000), allow_negative_numbers = true)]
    iterations: u32,
    #[command(flatten)]
    model: ModelArgs,
}

/// `twin distance`
#[derive(Debug, Args)]
pub struct DistanceArgs {
    /// Joint angles (rad): j1,j2,j3,j4,j5.
    #[arg(long, value_parser = parse_joints, allow_hyphen_values = true)]
    joints: Joints,
    /// A box (m): centre and full sizes cx,cy,cz,sx,sy,sz; repeat for more boxes.
    #[arg(long = "box", value_parser = parse_box, allow_hyphen_values = true, required = true)]
    boxes: Vec<BoxObstacle>,
    #[command(flatten)]
    model: ModelArgs,
}

/// `twin rollout`
#[derive(Debug, Args)]
pub struct RolloutArgs {
    /// Scene file (TOML); without it every episode samples a scene from the task file.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Number of episodes.
    #[arg(long, default_value_t = 1, value_parser = int_within(1u32, 10_000_000), allow_negative_numbers = true)]
    episodes: u32,
    /// Seed of the scene sampling and of the action noise.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    seed: u64,
    /// Obstacle class of sampled scenes: small or large.
    #[arg(long, default_value = "small", value_parser = parse_class)]
    class: ObstacleClass,
    /// Standard deviation-like amplitude of uniform noise added to the scripted actions.
    #[arg(long, default_value_t = 0.0, value_parser = f32_within(0.0, 1.0), allow_negative_numbers = true)]
    noise: f32,
    /// Task file (default: the bundled assets/task.toml).
    #[arg(long)]
    task: Option<PathBuf>,
    #[command(flatten)]
    model: ModelArgs,
}

fn parse_list<const N: usize>(s: &str, what: &str) -> Result<[f64; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!(
            "expected {N} comma-separated {what}, got {}",
            parts.len()
        ));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(parts) {
        let v: f64 = p.parse().map_err(|_| format!("`{p}` is not a number"))?;
        if !v.is_finite() {
            return Err(format!("`{p}` is not finite"));
        }
        *o = v;
    }
    Ok(out)
}

fn parse_joints(s: &str) -> Result<Joints, String> {
    parse_list::<DOF>(s, "joint angles (rad)")
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    parse_list::<3>(s, "coordinates (m)")
}

fn parse_box(s: &str) -> Result<BoxObstacle, String> {
    let v = parse_list::<6>(s, "values cx,cy,cz,sx,sy,sz (m)")?;
    if v[3..].iter().any(|x| *x <= 0.0) {
        return Err("box sizes must be positive".into());
    }
    Ok(BoxObstacle {
        center_m: [v[0], v[1], v[2]],
        size_m: [v[3], v[4], v[5]],
    })
}

fn parse_class(s: &str) -> Result<ObstacleClass, String> {
    match s {
        "small" => Ok(ObstacleClass::Small),
        "large" => Ok(ObstacleClass::Large),
        _ => Err(format!("unknown obstacle class `{s}` (small or large)")),
    }
}

/// The bundled assets folder: `$FORESIGHT_ASSETS`, else `./assets`, else the source tree's.
fn asset(name: &str) -> PathBuf {
    if let Some(dir) = std::env::var_os("FORESIGHT_ASSETS") {
        return Path::new(&dir).join(name);
    }
    let local = Path::new("assets").join(name);
    if local.exists() {
        return local;
    }
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets")).join(name)
}

fn load_model(args: &ModelArgs) -> anyhow::Result<RobotModel> {
    let path = args.urdf.clone().unwrap_or_else(|| asset("xarm5.urdf"));
    RobotModel::load(&path).with_context(|| format!("loading the robot model {}", path.display()))
}

fn round(v: f64) -> f64 {
    (v * 1e9).round() / 1e9
}

fn arr(v: &[f64]) -> Value {
    Value::from(v.iter().map(|x| round(*x)).collect::<Vec<_>>())
}

fn fk(args: &FkArgs) -> anyhow::Result<Value> {
    let model = load_model(&args.model)?;
    let poses = model.fk(&args.joints);
    let links: Vec<Value> = (0..N_FRAMES)
        .map(|i| {
            let l = &poses.links[i];
            let q = l.rotation.coords;
            json!({
                "name": model.link_name(i),
                "pos": arr(l.translation.vector.as_slice()),
                "quat": arr(&[q.x, q.y, q.z, q.w]),
            })
        })
        .collect();
    Ok(json!({ "tcp": arr(poses.tcp_m().as_slice()), "links": links }))
}

fn ik(args: &IkArgs) -> anyhow::Result<Value> {
    let model = load_model(&args.model)?;
    let cfg = IkConfig {
        max_iterations: args.iterations.max(1),
        ..IkConfig::default()
    };
    let solver = IkSolver::new(&model, cfg);
    let from = args.from.unwrap_or_else(|| model.home());
    let r = solver.solve(&model, &Vector3::from(args.target), &from);
    Ok(json!({ "joints": arr(&r.joints), "reached": r.reached, "error_m": round(r.error_m) }))
}

fn distance(args: &DistanceArgs) -> anyhow::Result<Value> {
    let model = load_model(&args.model)?;
    if args.boxes.len() > MAX_OBSTACLES {
        bail!("at most {MAX_OBSTACLES} boxes");
    }
    let mut scene = Scene::empty(
        0.0,
        Goal {
            center_m: [0.0; 3],
            size_m: 0.05,
        },
    );
    for b in &args.boxes {
        let _ = scene.obstacles.push(*b);
    }
    let geometry = RobotGeometry::new(&model);
    let poses = model.fk(&args.joints);
    let Some(d) = geometry.distance_to_boxes(&poses, &scene) else {
        bail!("no box given");
    };
    Ok(json!({
        "distance_m": round(d.distance_m),
        "robot_point": arr(&d.robot_point_m),
        "obstacle_point": arr(&d.obstacle_point_m),
        "link": model.link_name(d.link),
        "colliding": d.colliding,
    }))
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn rollouts(args: &RolloutArgs) -> anyhow::Result<Value> {
    let model = load_model(&args.model)?;
    let task_path = args.task.clone().unwrap_or_else(|| asset("task.toml"));
    let cfg = TaskConfig::load(&task_path)
        .with_context(|| format!("loading the task {}", task_path.display()))?;
    if args.episodes == 0 || args.episodes > 100_000 {
        bail!("--episodes must be in 1..=100000");
    }
    if !(args.noise.is_finite() && (0.0..=1.0).contains(&args.noise)) {
        bail!("--noise must be in [0, 1]");
    }
    let fixed = match &args.scene {
        Some(path) => {
            let file = SceneFile::load(path)?;
            Some(Scene::from_file(&file).with_context(|| format!("scene {}", path.display()))?)
        }
        None => None,
    };
    let mut env = TwinEnv::new(model, cfg);
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let mut episodes = Vec::new();
    let mut episode_ms = Vec::new();
    let mut step_us = Vec::new();
    let started = Instant::now();
    for _ in 0..args.episodes {
        let scene = match &fixed {
            Some(s) => *s,
            None => env.sample_scene(&mut rng, args.class),
        };
        env.reset(&scene);
        let policy = env.straight_line_policy();
        let noise = args.noise;
        let t0 = Instant::now();
        let summary = rollout(
            &mut env,
            &scene,
            |obs| {
                let mut a = policy.act(obs);
                if noise > 0.0 {
                    for v in &mut a {
                        *v += noise * (rng.random::<f32>() * 2.0 - 1.0);
                    }
                }
                a
            },
            None,
        );
        let dt_s = t0.elapsed().as_secs_f64();
        episode_ms.push(dt_s * 1e3);
        step_us.push(dt_s * 1e6 / f64::from(summary.steps.max(1)));
        episodes.push(json!({
            "success": summary.success,
            "safe": summary.safe,
            "return": round(summary.return_),
            "steps": summary.steps,
            "min_distance_m": round(summary.min_distance_m),
        }));
    }
    let total_s = started.elapsed().as_secs_f64();
    let successes = episodes.iter().filter(|e| e["success"] == true).count();
    let safe = episodes.iter().filter(|e| e["safe"] == true).count();
    Ok(json!({
        "policy": "straight_line",
        "task_hash": format!("{:016x}", env.config().hash()),
        "episodes": episodes,
        "success_rate": successes as f64 / f64::from(args.episodes),
        "safe_rate": safe as f64 / f64::from(args.episodes),
        "timing": {
            "total_s": round(total_s),
            "episode_ms_median": round(median(&mut episode_ms)),
            "step_us_median": round(median(&mut step_us)),
        },
    }))
}

/// Runs a twin query: prints one JSON object, or a message on stderr and exits with 2.
pub fn run(cmd: TwinCommand) -> ExitCode {
    let result = match &cmd {
        TwinCommand::Fk(a) => fk(a),
        TwinCommand::Ik(a) => ik(a),
        TwinCommand::Distance(a) => distance(a),
        TwinCommand::Rollout(a) => rollouts(a),
    };
    match result {
        Ok(v) => {
            println!("{v}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
