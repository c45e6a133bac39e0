#!/usr/bin/env bash
# The main job (`make demo`): the self-improving loop on the simulated arm.
# Usage: scripts/demo.sh <bin-dir> [foresight options...]
#   e.g. make demo ARGS="--no-lookahead"   or   make demo ARGS="--runs 20 --seed 7"
#   The planner fallback is on by default: when the lookahead predicts a collision, the
#   planner's checked path moves the arm while the learner retrains, and the retrained
#   policy replaces it. The paper's story (the arm waits for the retrained policy):
#   make demo ARGS="--planner-fallback off"
#   The default policy is the distilled generalist (assets/policy-distilled); the research
#   system's setting (its PPO generalist and its tall box):
#   make demo ARGS="--checkpoint assets/policy --world assets/scenes/paper_world.toml"
set -euo pipefail
bin=${1:?usage: demo.sh <bin-dir> [foresight options]}
shift
cd "$(dirname "$0")/.."
# iceoryx2 keeps shared memory of crashed processes; the launcher's nodes clean dead
# nodes at start, so nothing needs removing here.
exec "$bin/foresight" "$@"
