#!/usr/bin/env bash
# Re-create bags/reference/swingup_tap (committed; used by the tests): a lockstep simulator run,
# auto mode from hanging at rest -- swing-up, catch, balance -- and a tap of 0.4 rad/s at 7 s,
# 10 simulated seconds, the control-path topics only (no /clock, joint_states) to stay small.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=bags/reference/swingup_tap
rm -rf "$OUT"
mkdir -p bags/reference
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-77} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
./rwpend record -o "$OUT" /rwpend/encoders /rwpend/command /rwpend/state /rwpend/sim/true_state \
  /rwpend/controller/status /diagnostics &
REC=$!
./rwpend up --lockstep --mode auto --duration 10 --tap 7:0.4 \
  --set sim.start.encoders_subscribers=2 --set sim.start.true_state_subscribers=1
kill -INT $REC
wait $REC
./rwpend bag info "$OUT"
