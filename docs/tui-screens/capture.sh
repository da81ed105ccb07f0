#!/usr/bin/env bash
# Text captures of every console screen (tmux send-keys / capture-pane), on a simulated lab with
# the analytic world at time scale 0: the operator session of docs/tui.md, reproduced.
# Usage: docs/tui-screens/capture.sh [OUTDIR] [COLSxROWS]  (default: docs/tui-screens, 80x24;
# try 160x45 too).  Needs tmux.  Takes about a minute.
set -euo pipefail
REPO="$(cd "$(dirname "$0")/../.." && pwd)"
OUT="$(cd "${1:-$REPO/docs/tui-screens}" && pwd)"
SIZE="${2:-80x24}"; COLS="${SIZE%x*}"; ROWS="${SIZE#*x}"
NB="$REPO/.venv/bin/normbox-lab"
PY="$REPO/.venv/bin/python"
WORK="$(mktemp -d)"
cd "$WORK"
S=normbox-tui-capture

grab() { tmux capture-pane -p -t "$S" > "$OUT/$1.txt"; }
waitfor() {  # waitfor TEXT [seconds]
  for _ in $(seq 1 $((${2:-20} * 10))); do
    tmux capture-pane -p -t "$S" | grep -qF -- "$1" && return 0
    sleep 0.1
  done
  echo "timed out waiting for: $1" >&2; tmux capture-pane -p -t "$S" >&2; return 1
}
N=0
start() {  # a new session before the old one goes: killing the last session stops the tmux
           # server, and a session started at that moment fails ("server exited unexpectedly")
  local old="$S"; N=$((N + 1)); S="normbox-tui-capture-$N"
  tmux new-session -d -s "$S" -x "$COLS" -y "$ROWS" "$*; echo '[console closed]'; sleep 600"
  tmux kill-session -t "=$old" 2>/dev/null || true; }
answer() {  # answer the operator prompt on screen, then wait until that prompt has gone
  waitfor "then Enter" 30
  local key; key="$(tmux capture-pane -p -t "$S" | grep -o 'Operator  [^ ]*' | head -1)"
  tmux send-keys -t "$S" Enter
  for _ in $(seq 1 300); do
    tmux capture-pane -p -t "$S" | grep -qF -- "$key" || return 0
    sleep 0.1
  done
}

# 1. a reduced reference sweep: dry-run, prompts, pause, resume, the end
start "$NB tui --world analytic --time-scale 0 --store cap.sqlite --param angles_deg=[30,60,90] --param patches=[1,9,19]"
waitfor "virtual clock"; grab 01-run-tab
tmux send-keys -t "$S" d; waitfor "dry-run reference-sweep"; grab 02-dry-run
tmux send-keys -t "$S" s; waitfor "then Enter"; grab 03-operator-prompt
answer; answer
waitfor "then Enter"; tmux send-keys -t "$S" p; sleep 0.3; tmux send-keys -t "$S" Enter
waitfor "paused before"; grab 04-paused
tmux send-keys -t "$S" p
for _ in 1 2 3 4 5 6; do answer; done
waitfor "run finished: done"; grab 05-run-done
tmux send-keys -t "$S" 1; sleep 1; grab 06-instruments
tmux send-keys -t "$S" 3; waitfor "wavelength nm"; grab 07-spectrum
tmux send-keys -t "$S" 4; waitfor "created"; sleep 0.5; grab 08-runs
sleep 0.5; tmux send-keys -t "$S" Enter; waitfor "event log"; grab 16-event-log
tmux send-keys -t "$S" Escape; sleep 0.5
tmux send-keys -t "$S" Tab Enter; waitfor "Esc / Enter: close"; grab 17-reading-spectrum
tmux send-keys -t "$S" Escape; sleep 0.5
tmux send-keys -t "$S" 1; sleep 0.5; tmux send-keys -t "$S" h; waitfor "rotator homed"; grab 18-manual-home
tmux send-keys -t "$S" g; waitfor "go to angle"; tmux send-keys -t "$S" 4 5 Enter
waitfor "rotator at 45.00"; tmux send-keys -t "$S" m; waitfor "single reading taken"
grab 19-manual-reading
"$PY" "$REPO/docs/tui-screens/synthetic_comparison.py" cap.sqlite > /dev/null
tmux send-keys -t "$S" 5; waitfor "NRMSE %"; grab 09-results
tmux send-keys -t "$S" Enter; waitfor "L*a*b* measured"; grab 10-drill-down
tmux send-keys -t "$S" Escape; sleep 0.5; tmux send-keys -t "$S" e; waitfor "exported run"; grab 11-export

# 2. look at another tab while a prompt waits, then quit in the middle of the run: the run
#    pauses and can be resumed
tmux send-keys -t "$S" 2 s; answer; answer; waitfor "then Enter"
tmux send-keys -t "$S" 4; waitfor "prompt waiting: w"; grab 20-prompt-aside
tmux send-keys -t "$S" w; waitfor "then Enter"
tmux send-keys -t "$S" q; waitfor "[console closed]"; grab 12-quit-mid-run

# 3. the next start offers to resume it
start "$NB tui --world analytic --time-scale 0 --store cap.sqlite"
waitfor "interrupted run"; grab 13-resume-offer
tmux send-keys -t "$S" Enter; waitfor "then Enter"; tmux send-keys -t "$S" a; sleep 0.3
tmux send-keys -t "$S" a                                   # abort asks: a again confirms
waitfor "run finished: aborted"; tmux send-keys -t "$S" q

# 4. a radiometer that never answers: the fault prompt while preparing it (retry / abort)
"$NB" init lab.toml --sim > /dev/null
sed -i 's|^port = "sim://cs1000a"|port = "sim://cs1000a?faults=no-reply=1.0"|' lab.toml
start "$NB tui --lab lab.toml --world analytic --store faults.sqlite --param angles_deg=[30] --param patches=[1]"
waitfor "virtual clock"; tmux send-keys -t "$S" s
waitfor "r retry · a abort" 60; grab 14-fault-prompt
tmux send-keys -t "$S" a; waitfor "run finished" 30; tmux send-keys -t "$S" q
sleep 0.5
tmux kill-session -t "$S" 2>/dev/null || true
echo "captures in $OUT; work dir $WORK"
