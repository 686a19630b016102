#!/usr/bin/env bash
# Build the package with colcon into a scratch workspace and start one installed executable:
# `sim_robot` must come up, keep running, and exit cleanly on SIGINT.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
ws="$(mktemp -d)"
trap 'rm -rf "$ws"' EXIT
cd "$ws"
colcon build --base-paths "$repo" --build-base "$ws/build" --install-base "$ws/install" \
  --event-handlers console_direct- > "$ws/colcon.log" 2>&1 || { cat "$ws/colcon.log"; exit 1; }
exe="$ws/install/policy_align_ros/lib/policy_align_ros/sim_robot"
test -x "$exe" || { echo "colcon smoke: $exe not installed"; exit 1; }
launch="$ws/install/policy_align_ros/share/policy_align_ros/launch/policy_align.launch.py"
test -f "$launch" || { echo "colcon smoke: $launch not installed"; exit 1; }
# The robot configs every node reads (sim_robot below reads talos.yaml from here).
for robot in talos panda ur5; do
  config="$ws/install/policy_align_ros/share/policy_align_ros/config/robots/$robot.yaml"
  test -f "$config" || { echo "colcon smoke: $config not installed"; exit 1; }
done
set +u; source "$ws/install/setup.bash"; set -u
export ROS_DOMAIN_ID=$(( 230 + RANDOM % 2 ))
"$exe" --ros-args -p robot_config:=ur5 > "$ws/node.log" 2>&1 &
pid=$!
sleep 5
if ! kill -0 "$pid" 2>/dev/null; then
  echo "colcon smoke: installed sim_robot exited early:"; cat "$ws/node.log"; exit 1
fi
kill -INT "$pid"
if ! wait "$pid"; then echo "colcon smoke: sim_robot did not exit cleanly:"; cat "$ws/node.log"; exit 1; fi
grep -q "simulating ur5 with 6 joints" "$ws/node.log" || {
  echo "colcon smoke: sim_robot did not take the installed ur5 robot config:"; cat "$ws/node.log"; exit 1; }
echo "colcon smoke: built policy_align_ros and ran installed sim_robot ($exe) on robot_config ur5"
