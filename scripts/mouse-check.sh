#!/usr/bin/env bash
# Drives the organs app with a real (virtual) mouse on a machine without a display: Xvfb, the
# app in `--screenshot --mouse` mode (the mouse, not the script, moves the tool), and xdotool
# moving the pointer over the liver, pushing the tool deeper with the wheel until the app logs a
# touch (PUSH more lines, default 0), saving the poke with F12 (organs-mouse.png), then pressing
# the left button (pick), dragging up and saving again (organs-mouse-2.png). Keeps the app's
# log; fails if the tool never touched or a picture is missing.
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
rm -f "$out/organs-mouse.png" "$out/organs-mouse-2.png"
WGPU_BACKEND=vulkan RUST_LOG=info "$target/debug/examples/organs" --screenshot "$out/organs-mouse.png" \
    --frames 100000 --mouse > "$out/organs-mouse.log" 2>&1 &
app=$!
win=
for _ in $(seq 120); do
    win=$(xdotool search --name "organs" 2>/dev/null | head -1) && [ -n "$win" ] && break
    sleep 1
done
# No window manager under Xvfb: give the window the keyboard focus for F12.
xdotool windowfocus "$win" 2>/dev/null || true
sleep "${SETTLE:-10}"
# Over the liver (right of the screen centre); the wheel pushes the tool farther, one line at
# a time, until the app logs that it touches, then PUSH lines more (a poke); then pick and drag.
xdotool mousemove 860 300
sleep 2
touched=no
for _ in $(seq "${MAX_CLICKS:-40}"); do
    if grep -q "tool touches" "$out/organs-mouse.log"; then touched=yes; break; fi
    xdotool click 5
    sleep "${CLICK_PAUSE:-1}"
done
echo "touched: $touched"
for _ in $(seq "${PUSH:-0}"); do xdotool click 5; sleep "${CLICK_PAUSE:-1}"; done
# The poke, held: first picture (F12). Then pick (left button) and drag up: second picture.
sleep 3
xdotool key F12
sleep 2
xdotool mousedown 1
sleep 1
for y in 296 292 288 284 280; do xdotool mousemove 860 "$y"; sleep 0.4; done
sleep 2
xdotool key F12
sleep 4
kill "$app" 2>/dev/null || { tail -20 "$out/organs-mouse.log"; exit 1; }
wait "$app" || true
ls -la "$out/organs-mouse.png" "$out/organs-mouse-2.png"
grep "touches\|leaves" "$out/organs-mouse.log" || true
[ "$touched" = yes ]
