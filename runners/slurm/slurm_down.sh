#!/usr/bin/env bash
# Stop the single-node SLURM cluster started by runners/slurm/slurm_up.sh.
#
# Order matters:
#   1. cancel the remaining jobs (slurmd would otherwise leave their processes behind),
#   2. let slurmctld hand its queued job records to slurmdbd, then stop slurmd and slurmctld,
#   3. stop slurmdbd (after slurmctld, so that the last records still reach the database),
#   4. stop MariaDB and munged (everything above needs them while it shuts down).
#
# Only the processes named by the daemons' PID files are signalled (never a kill-by-name), and a
# PID file is trusted only if its process still has the expected name. Safe to run when nothing,
# or only part of the cluster, is running: it then does nothing for the missing parts.
set -euo pipefail

readonly SLURMCTLD_PID=/run/slurmctld.pid
readonly SLURMD_PID=/run/slurmd.pid
readonly SLURMDBD_PID=/run/slurmdbd.pid
readonly MARIADB_PID=/run/mysqld/mysqld.pid
readonly MUNGED_PID=/run/munge/munged.pid
export PATH=$PATH:/usr/sbin

say() { echo "slurm_down: $*"; }

[[ $(id -u) == 0 ]] || { echo "slurm_down: must run as root" >&2; exit 1; }

# pid_of PIDFILE COMM: print the PID if PIDFILE names a live (non-zombie) process called COMM.
# The name check keeps a stale PID file (e.g. after a reboot) from killing an unrelated process.
pid_of() {
  local pid
  [[ -s $1 ]] || return 1
  pid=$(tr -dc '0-9' <"$1")
  [[ -n $pid && $(cat "/proc/$pid/comm" 2>/dev/null) == "$2" ]] || return 1
  [[ $(awk '{print $3}' "/proc/$pid/stat" 2>/dev/null) != Z ]] || return 1
  echo "$pid"
}

# stop TIMEOUT PIDFILE:COMM...: SIGTERM all given daemons at once, wait up to TIMEOUT seconds for
# them to exit (each takes 1-2 s to shut down cleanly), SIGKILL what is left, remove the PID files.
stop() {
  local timeout=$1 spec pidfile comm pid deadline pids=() names=()
  shift
  for spec in "$@"; do
    pidfile=${spec%%:*} comm=${spec#*:}
    if pid=$(pid_of "$pidfile" "$comm"); then
      kill -TERM "$pid" 2>/dev/null || true
      pids+=("$pid") names+=("$comm")
    fi
  done
  deadline=$((SECONDS + timeout))
  for i in "${!pids[@]}"; do
    # A zombie counts as gone: it has exited, only its parent has not reaped it yet.
    while kill -0 "${pids[$i]}" 2>/dev/null && [[ $(awk '{print $3}' "/proc/${pids[$i]}/stat" 2>/dev/null) != Z ]]; do
      if ((SECONDS >= deadline)); then
        say "${names[$i]} (pid ${pids[$i]}) ignored SIGTERM for ${timeout}s: SIGKILL"
        kill -KILL "${pids[$i]}" 2>/dev/null || true
        break
      fi
      sleep 0.1
    done
    say "stopped ${names[$i]} (pid ${pids[$i]})"
  done
  for spec in "$@"; do rm -f "${spec%%:*}"; done
}

# 1. Cancel the remaining jobs, if the controller is up to ask. KillWait=5 in slurm.conf bounds the
#    time a job may take to exit after SIGTERM.
if pid_of "$SLURMCTLD_PID" slurmctld >/dev/null && timeout 10 scontrol ping >/dev/null 2>&1; then
  # %F: the array's job id for array tasks (cancels the whole array at once), else the job id.
  jobs=$(timeout 10 squeue -h -o '%F' 2>/dev/null | sort -u || true)
  if [[ -n $jobs ]]; then
    say "cancelling jobs: ${jobs//$'\n'/ }"
    # shellcheck disable=SC2086  # one argument per job id
    timeout 10 scancel $jobs 2>/dev/null || true
    deadline=$((SECONDS + 15))
    while [[ -n $(timeout 10 squeue -h -o '%A' 2>/dev/null || true) ]] && ((SECONDS < deadline)); do
      sleep 0.25
    done
    [[ -z $(timeout 10 squeue -h -o '%A' 2>/dev/null || true) ]] || say "warning: jobs still listed after 15 s"
  fi
  # 2. slurmctld sends job records to slurmdbd asynchronously (about 2 s behind). Wait, briefly,
  #    for its queue to drain so that the last jobs' records are not lost.
  deadline=$((SECONDS + 5))
  until [[ $(timeout 10 sdiag 2>/dev/null | awk -F': *' '/DBD Agent queue size/ {print $2}') == 0 ]] \
        || ((SECONDS >= deadline)); do
    sleep 0.25
  done
fi

stop 15 "$SLURMD_PID:slurmd" "$SLURMCTLD_PID:slurmctld"
# 3.
stop 15 "$SLURMDBD_PID:slurmdbd"
# 4. MariaDB flushes its buffers on SIGTERM; give it longer before a SIGKILL.
stop 30 "$MARIADB_PID:mariadbd" "$MUNGED_PID:munged"
say "done"
