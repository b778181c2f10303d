#!/usr/bin/env bash
# Capture the README's editor session: Neovim's built-in LSP client, started by init.lua on
# mistakes.mech in a detached tmux session, with `mechdsl lsp` as its server. Writes what the
# terminal shows to docs/images/nvim-diagnostics.txt (the file as it opens), nvim-hover.txt
# (K on the prismatic type) and nvim-hover-point.txt (K on rod.B, whose coordinates the
# server evaluates although the file has errors). Needs nvim (0.7 or newer) and tmux; run from
# anywhere, with mechdsl on the PATH or MECHDSL_LSP naming the server's command line.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
out="$root/docs/images"
session=mechdsl-capture-$$
cd "$root"

tmux new-session -d -s "$session" -x 128 -y 32 \
    "nvim --clean -u editors/nvim/init.lua editors/nvim/mistakes.mech"
trap 'tmux kill-session -t "$session" 2>/dev/null || true' EXIT

screen() { tmux capture-pane -p -t "$session" | sed -e 's/[[:space:]]*$//'; }
wait_for() {  # a text on the screen, within 20 s
    for _ in $(seq 200); do
        if screen | grep -qF -- "$1"; then return 0; fi
        sleep 0.1
    done
    echo "capture: '$1' never appeared" >&2; screen >&2; exit 1
}

wait_for "unknown name 'omga'"
screen > "$out/nvim-diagnostics.txt"

tmux send-keys -t "$session" ":25" Enter "0" "fp" "K"
wait_for "joint type prismatic"
screen > "$out/nvim-hover.txt"

tmux send-keys -t "$session" Escape ":23" Enter "0" "/rod.B" Enter "llll" "K"
wait_for "point rod.B"
screen > "$out/nvim-hover-point.txt"
tmux send-keys -t "$session" Escape ":qa!" Enter
echo "capture: wrote $out/nvim-diagnostics.txt, nvim-hover.txt, nvim-hover-point.txt"
