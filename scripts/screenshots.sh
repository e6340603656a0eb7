#!/usr/bin/env bash
# Renders both example apps on a machine without a GPU or a display and saves a PNG of each
# with a scripted interaction under way: software Vulkan (Mesa's lavapipe) in a real window
# under Xvfb, so the egui panels show too.
#
#   scripts/screenshots.sh [OUT_DIR]      (default docs/screenshots)
#
# Installs what it needs (Debian: xvfb, xauth, mesa-vulkan-drivers, libvulkan1) when missing.
# Builds what `cargo test --workspace` builds (the examples included, with the same features),
# so after the tests nothing is rebuilt.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-docs/screenshots}
mkdir -p "$out"

need=()
command -v xvfb-run >/dev/null || need+=(xvfb xauth)
[ -e /usr/share/vulkan/icd.d/lvp_icd.x86_64.json ] || ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || need+=(mesa-vulkan-drivers)
ldconfig -p | grep -q libvulkan.so.1 || need+=(libvulkan1)
if [ ${#need[@]} -gt 0 ]; then
    echo "installing ${need[*]}"
    sudo_cmd=()
    [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
    export DEBIAN_FRONTEND=noninteractive
    "${sudo_cmd[@]}" apt-get install -y --no-install-recommends "${need[@]}" >/dev/null ||
        { "${sudo_cmd[@]}" apt-get update >/dev/null && "${sudo_cmd[@]}" apt-get install -y --no-install-recommends "${need[@]}" >/dev/null; }
fi

target=${CARGO_TARGET_DIR:-target}
cargo test -q --workspace --no-run --locked

# Frames at 1/60 s of simulated time each: organs 150 (2.5 s, the cautery pressing on the
# liver), cylinders 130 (2.2 s, model A pushed into model B), organs-burn 230 (3.8 s, close
# up: the burn the cautery left on the liver, the tool lifted off). PNG:APP:FRAMES[:OPTION].
for shot in organs:organs:150 cylinders:cylinders:130 organs-burn:organs:230:--close-up; do
    IFS=: read -r name app frames extra <<< "$shot"
    png="$out/$name.png"
    rm -f "$png"
    WGPU_BACKEND=vulkan timeout 600 xvfb-run -a -s "-screen 0 1280x720x24" \
        "$target/debug/examples/$app" --screenshot "$png" --frames "$frames" $extra \
        > "/tmp/soft-tissue-$name.log" 2>&1 || { tail -20 "/tmp/soft-tissue-$name.log"; exit 1; }
    size=$(stat -c %s "$png")
    # A blank or failed frame compresses to almost nothing.
    if [ "$size" -lt 20000 ]; then
        echo "$png is only $size bytes: the frame looks empty" >&2
        exit 1
    fi
    echo "ok $png ($size bytes)"
done
