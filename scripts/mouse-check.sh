#!/usr/bin/env bash
# Drives the organs app with a real (virtual) mouse on a machine without a display: Xvfb, the
# app in `--screenshot --mouse` mode (the mouse, not the script, moves the tool), and xdotool
# moving the pointer over the liver, pushing the tool deeper with the wheel, pressing the left
# button (pick) and dragging. Saves the window as a PNG and the app's log.
#
#   scripts/mouse-check.sh [OUT_DIR]     (default /tmp/mouse-check; needs a built test profile)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-/tmp/mouse-check}
mkdir -p "$out"
need=()
command -v Xvfb >/dev/null || need+=(xvfb)
command -v xdotool >/dev/null || need+=(xdotool)
if [ ${#need[@]} -gt 0 ]; then
    sudo_cmd=()
    [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y --no-install-recommends "${need[@]}" >/dev/null
fi
target=${CARGO_TARGET_DIR:-target}
display=:97
Xvfb "$display" -screen 0 1280x720x24 >/dev/null 2>&1 &
xvfb=$!
trap 'kill $xvfb 2>/dev/null || true' EXIT
export DISPLAY=$display
rm -f "$out/organs-mouse.png"
WGPU_BACKEND=vulkan RUST_LOG=info "$target/debug/examples/organs" --screenshot "$out/organs-mouse.png" \
    --frames "${FRAMES:-400}" --mouse > "$out/organs-mouse.log" 2>&1 &
app=$!
for _ in $(seq 120); do
    xdotool search --name "organs" >/dev/null 2>&1 && break
    sleep 1
done
sleep "${SETTLE:-10}"
# Over the liver (right of the screen centre), then deeper with the wheel, then pick and drag.
xdotool mousemove 860 300
sleep 2
for _ in $(seq "${CLICKS:-2}"); do xdotool click 5; sleep 0.5; done
sleep 3
xdotool mousedown 1
sleep 1
for y in 295 290 285 280 275 270; do xdotool mousemove 860 "$y"; sleep 0.4; done
wait "$app" || { tail -20 "$out/organs-mouse.log"; exit 1; }
ls -la "$out/organs-mouse.png"
