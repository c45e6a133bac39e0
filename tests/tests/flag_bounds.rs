//! Every numeric flag of every binary refuses `NaN`, `inf`, a negative and a huge value
//! with a clear error naming the flag, a non-zero exit and no panic (issue 25 item 13).
//!
//! The table below lists the numeric flags of `foresight`, `rt-core`, `learner`,
//! `unseen-worlds`, `perception`, `xarm-sim`, `zenoh-relay` and `ros-bridge`; a completeness check reads each
//! command's `--help` and fails for a flag whose default is a number but that the table does
//! not list (a new numeric flag needs a row, and a bound: `shm_schemas::cli_bounds`).
//!
//! Each command runs in an empty temporary folder (no assets, nothing written to the
//! repository) inside a private network namespace (`run_in_private_netns`), and is killed
//! after 20 s: a command that accepted the value and went on to run fails the test. Needs the
//! binaries built (`scripts/cargo.sh build --release -p launcher -p rt-core -p learner
//! -p unseen-worlds -p perception -p xarm-sim -p zenoh-relay -p ros-bridge --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use foresight_tests::{NetnsOutcome, bin_path, run_in_private_netns};

/// What a flag takes.
#[derive(Debug, Clone, Copy)]
enum Kind {
    /// A float: `NaN`, `inf`, `-1`, `1e300` are refused.
    Float,
    /// An integer: `NaN`, `inf`, `-1`, `99999999999999999999999` are refused.
    Int,
    /// A float list or tuple: the bad value is written into `template` at `{}`, and the
    /// negative one is `neg` (where -1 is a valid value, e.g. a joint angle).
    FloatIn {
        template: &'static str,
        neg: &'static str,
    },
}

impl Kind {
    fn bad_values(self) -> Vec<String> {
        match self {
            Self::Float => ["NaN", "inf", "-1", "1e300"].map(String::from).to_vec(),
            Self::Int => ["NaN", "inf", "-1", "99999999999999999999999"]
                .map(String::from)
                .to_vec(),
            Self::FloatIn { template, neg } => ["NaN", "inf", neg, "1e300"]
                .iter()
                .map(|v| template.replace("{}", v))
                .collect(),
        }
    }
}

use Kind::{Float as F, Int as I};

/// One command: the binary, the arguments before the flag (subcommand and required
/// arguments), its numeric flags.
struct Cmd {
    bin: &'static str,
    args: &'static [&'static str],
    flags: &'static [(&'static str, Kind)],
}

/// The flags of `learner`'s PPO settings (pretrain, bench).
const PPO: [(&str, Kind); 9] = [
    ("--envs", I),
    ("--workers", I),
    ("--n-steps", I),
    ("--batch", I),
    ("--epochs", I),
    ("--lr", F),
    ("--hidden", I),
    ("--ent-coef", F),
    ("--torch-threads", I),
];

/// The flags of one retraining (`learner::retrain::RetrainFlags`: `learner serve`,
/// `learner retrain`, `unseen-worlds`).
const RETRAIN: [(&str, Kind); 17] = [
    ("--max-steps", I),
    ("--time-budget-s", F),
    ("--eval-every", I),
    ("--eval-episodes", I),
    ("--eval-jitter", F),
    ("--old-share", F),
    ("--explore-std", F),
    ("--batch", I),
    ("--epochs", I),
    ("--lr", F),
    ("--ent-coef", F),
    ("--height-start", F),
    ("--workers", I),
    ("--kept-episodes", I),
    ("--planner-budget-s", F),
    ("--demo-variants", I),
    ("--bc-steps", I),
];

/// The real-time options of `rt-core run` and `bench-loop`.
const RT: [(&str, Kind); 2] = [("--cpu", I), ("--rt-priority", I)];

fn table() -> Vec<Cmd> {
    fn cat(parts: &[&'static [(&'static str, Kind)]]) -> &'static [(&'static str, Kind)] {
        Vec::leak(parts.concat())
    }
    vec![
        Cmd {
            bin: "foresight",
            args: &[],
            flags: &[
                ("--camera-rate-hz", F),
                ("--runs", I),
                ("--seed", I),
                ("--retrain-budget-s", F),
                ("--retrain-steps", I),
                ("--learner-delay-s", F),
                ("--phase-timeout-s", F),
                ("--record-max-mib", I),
            ],
        },
        Cmd {
            bin: "rt-core",
            args: &["run"],
            flags: cat(&[&[("--seconds", F), ("--report-port", I)], &RT]),
        },
        Cmd {
            bin: "rt-core",
            args: &["bench-loop"],
            flags: cat(&[
                &[("--rate", F), ("--seconds", F), ("--swap-every-ms", I)],
                &RT,
            ]),
        },
        Cmd {
            bin: "rt-core",
            args: &["twin", "ik", "--target", "0.3,0.0,0.2"],
            flags: &[("--iterations", I)],
        },
        Cmd {
            bin: "rt-core",
            args: &["twin", "rollout"],
            flags: &[("--episodes", I), ("--seed", I), ("--noise", F)],
        },
        Cmd {
            bin: "rt-core",
            args: &["xarm", "probe", "--addr", "127.0.0.1"],
            flags: &[
                ("--report-port", I),
                ("--amplitude-deg", F),
                ("--duration-s", F),
            ],
        },
        Cmd {
            bin: "learner",
            args: &["pretrain"],
            flags: cat(&[
                &[
                    ("--steps", I),
                    ("--seed", I),
                    ("--eval-every", I),
                    ("--eval-episodes", I),
                    ("--time-budget-s", F),
                    ("--lr-final", F),
                    ("--harder-share", F),
                ],
                &PPO,
            ]),
        },
        Cmd {
            bin: "learner",
            args: &["bench"],
            flags: cat(&[&[("--steps", I), ("--seed", I)], &PPO]),
        },
        Cmd {
            bin: "learner",
            args: &["eval"],
            flags: &[("--episodes", I)],
        },
        Cmd {
            bin: "learner",
            args: &["export"],
            flags: &[("--policy-id", I)],
        },
        Cmd {
            bin: "learner",
            args: &["serve"],
            flags: cat(&[&RETRAIN, &[("--max-requests", I), ("--publish-delay-s", F)]]),
        },
        Cmd {
            bin: "learner",
            args: &["retrain", "--scene", "scene.toml"],
            flags: cat(&[&RETRAIN, &[("--world-seed", I)]]),
        },
        Cmd {
            bin: "unseen-worlds",
            args: &[],
            flags: cat(&[
                &[("--worlds", I), ("--seed", I), ("--kept-eval-episodes", I)],
                &[
                    ("--sample-sigma", F),
                    ("--sample-correlation", F),
                    ("--sample-seed", I),
                    ("--sample-via-share", F),
                    ("--sample-threads", I),
                ],
                &RETRAIN,
            ]),
        },
        Cmd {
            bin: "learner",
            args: &["distil", "--out", "out"],
            flags: &[
                ("--worlds", I),
                ("--harder-share", F),
                ("--iterations", I),
                ("--bc-steps", I),
                ("--bc-lr", F),
                ("--noise-std", F),
                ("--margin-m", F),
                ("--hinge-margin-m", F),
                ("--hinge-weight", F),
                ("--eval-episodes", I),
                ("--seed", I),
                ("--threads", I),
            ],
        },
        Cmd {
            bin: "perception",
            args: &["run", "--source", "ros2"],
            flags: &[
                ("--rate", F),
                ("--frames", I),
                ("--persist-frames", I),
                ("--settle-frames", I),
                ("--settle-quiet-ms", I),
                ("--settle-motion-m", F),
                ("--min-goal-confidence", F),
                ("--min-obstacle-confidence", F),
                ("--camera-id", I),
                ("--threads", I),
            ],
        },
        Cmd {
            bin: "perception",
            args: &["calibrate", "--image", "image.png"],
            flags: &[("--table-height", F)],
        },
        Cmd {
            bin: "perception",
            args: &["detect", "--image", "image.png"],
            flags: &[("--repeat", I), ("--threads", I)],
        },
        Cmd {
            bin: "perception",
            args: &["render", "--scene", "scene.toml"],
            flags: &[("--at-s", F)],
        },
        Cmd {
            bin: "xarm-sim",
            args: &[],
            flags: &[
                ("--port-offset", I),
                ("--command-port", I),
                ("--report-rt-port", I),
                ("--report-normal-port", I),
                ("--report-rich-port", I),
                ("--report-real-port", I),
                ("--control-port", I),
                ("--contact-margin-m", F),
                (
                    "--q0-rad",
                    Kind::FloatIn {
                        template: "{},0,0,0,0",
                        neg: "-100",
                    },
                ),
                ("--max-joint-speed-rad-s", F),
                ("--max-tcp-speed-m-s", F),
                ("--servo-period-ms", F),
                ("--fault-tolerance", F),
            ],
        },
        Cmd {
            bin: "zenoh-relay",
            args: &["learner-host"],
            flags: &[("--time-budget-s", F), ("--max-steps", I)],
        },
        Cmd {
            bin: "ros-bridge",
            args: &[],
            flags: &[("--domain-id", I), ("--rate-hz", F), ("--seconds", F)],
        },
        Cmd {
            bin: "foresight",
            args: &["reach"],
            flags: &[
                (
                    "--goal",
                    Kind::FloatIn {
                        template: "{},0.1",
                        neg: "-20",
                    },
                ),
                ("--approach-height-m", F),
                ("--deadline-s", F),
                ("--cancel-after-s", F),
                ("--connect-timeout-s", F),
                ("--domain-id", I),
            ],
        },
    ]
}

/// How long one refused command may take (learner loads libtorch first).
const LIMIT: Duration = Duration::from_secs(20);

/// Runs `bin args…` in `cwd` (own process group, killed after [`LIMIT`]); `None` if it
/// had to be killed.
fn run(bin: &Path, args: &[String], cwd: &Path) -> Option<Output> {
    use std::os::unix::process::CommandExt;
    let mut child = Command::new(bin)
        .args(args)
        .current_dir(cwd)
        .env("NO_COLOR", "1")
        .env("RUST_BACKTRACE", "0")
        .env_remove("ROS_DOMAIN_ID")
        .process_group(0)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("starting {}: {e}", bin.display()));
    let t0 = Instant::now();
    let mut killed = false;
    while child.try_wait().ok().flatten().is_none() {
        if t0.elapsed() > LIMIT {
            let _ = Command::new("kill")
                .args(["-KILL", &format!("-{}", child.id())])
                .status();
            killed = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let out = child.wait_with_output().expect("collecting the output");
    (!killed).then_some(out)
}

/// The flags of a `--help` text whose default is a number.
fn numeric_defaults(help: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut current: Option<String> = None;
    for line in help.lines() {
        let t = line.trim_start();
        if let Some(rest) = t.strip_prefix("--").or_else(|| {
            // `-x, --flag <V>`
            t.split_once(", --").map(|(_, r)| r)
        }) && t.starts_with('-')
        {
            current = rest
                .split(|c: char| c.is_whitespace() || c == '=' || c == '<')
                .next()
                .map(|f| format!("--{f}"));
        }
        if let (Some(flag), Some(i)) = (&current, line.find("[default: ")) {
            let value = line[i + "[default: ".len()..]
                .split(']')
                .next()
                .unwrap_or_default();
            if value.parse::<f64>().is_ok() && !out.contains(flag) {
                out.push(flag.clone());
            }
        }
    }
    out
}

#[test]
fn every_numeric_flag_refuses_nan_inf_negative_and_huge_values_naming_the_flag() {
    let name = "every_numeric_flag_refuses_nan_inf_negative_and_huge_values_naming_the_flag";
    if run_in_private_netns(name) == NetnsOutcome::RanInChild {
        return;
    }
    let cwd = std::env::temp_dir().join(format!("foresight-flag-bounds-{}", std::process::id()));
    std::fs::create_dir_all(&cwd).expect("scratch folder");
    let mut failures = Vec::new();
    let mut checked = 0;
    for cmd in table() {
        let bin = bin_path(cmd.bin);
        let base: Vec<String> = cmd.args.iter().map(|s| (*s).to_owned()).collect();
        let what = format!("{} {}", cmd.bin, cmd.args.join(" "));
        // Completeness: every flag with a numeric default is in the table.
        let mut help_args = base
            .iter()
            .take_while(|a| !a.starts_with("--"))
            .cloned()
            .collect::<Vec<_>>();
        help_args.push("--help".into());
        let help = run(&bin, &help_args, &cwd).expect("--help returns");
        let help = String::from_utf8_lossy(&help.stdout).into_owned();
        for flag in numeric_defaults(&help) {
            if !cmd.flags.iter().any(|(f, _)| *f == flag) {
                failures.push(format!(
                    "{what}: {flag} has a numeric default but no row in flag_bounds.rs"
                ));
            }
        }
        for &(flag, kind) in cmd.flags {
            for bad in kind.bad_values() {
                let mut args = base.clone();
                args.extend([flag.to_owned(), bad.clone()]);
                checked += 1;
                let Some(out) = run(&bin, &args, &cwd) else {
                    failures.push(format!(
                        "{what} {flag} {bad}: still running after {LIMIT:?} (the value was accepted)"
                    ));
                    continue;
                };
                let stderr = String::from_utf8_lossy(&out.stderr);
                let code = out.status.code();
                if code.is_none_or(|c| c == 0) {
                    failures.push(format!(
                        "{what} {flag} {bad}: exit {:?}; stderr:\n{stderr}",
                        out.status
                    ));
                } else if stderr.contains("panicked") {
                    failures.push(format!("{what} {flag} {bad}: a panic:\n{stderr}"));
                } else if !stderr.contains(flag) {
                    failures.push(format!(
                        "{what} {flag} {bad}: the error does not name {flag}:\n{stderr}"
                    ));
                }
            }
        }
    }
    let _ = std::fs::remove_dir_all(&cwd);
    println!("{checked} flag values checked");
    assert!(
        failures.is_empty(),
        "{} of {checked} refused badly:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn the_help_parser_finds_numeric_defaults() {
    let help = "Options:\n      --rate <RATE>\n          Frame rate [default: 15]\n      --bind <BIND>\n          [default: 127.0.0.1]\n  -x, --phase-timeout-s <S>  Longest [default: 90]\n      --name <N>  [default: abc]\n";
    assert_eq!(numeric_defaults(help), ["--rate", "--phase-timeout-s"]);
}
