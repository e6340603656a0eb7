#!/usr/bin/env bash
# The plugin's step in a new user's app, in the default dev profile and with optimised
# dependencies (what README.md tells users to add). Two builds from scratch: about 3 and 10
# minutes on a 2-core VM. Prints one line per build and level.
set -euo pipefail
cd "$(dirname "$0")"
target="${NEW_USER_TARGET:-${TMPDIR:-/tmp}/new_user_app_target}"
echo "== default dev profile (dependencies unoptimised)"
CARGO_TARGET_DIR="$target/plain" cargo run -q
echo "== with [profile.dev.package.\"*\"] opt-level = 3"
CARGO_TARGET_DIR="$target/opt" cargo run -q --config 'profile.dev.package."*".opt-level=3'
