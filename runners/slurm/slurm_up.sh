#!/usr/bin/env bash
# Bring up a single-node SLURM cluster on this machine (node "localhost", partition "debug")
# with accounting, for the project's submitit / hydra-submitit-launcher sweeps and tests.
#
#   munged -> MariaDB -> slurmdbd -> slurmctld -> slurmd
#
# Run as root on Debian 12 with slurm-wlm, munge, slurmdbd and mariadb-server installed
# (`make slurm-up` installs them). No systemd is needed or used: every daemon is started directly
# and remembered by its PID file, which runners/slurm/slurm_down.sh uses to stop it again.
#
# Idempotent: a daemon that already runs (and answers) is left alone, so a second call, or a call
# after a partial start, only starts what is missing. The script waits until the node is usable
# and `sacctmgr` answers, then prints `sinfo`. On any failure it prints the daemons' log tails and
# exits non-zero.
#
# Environment:
#   SLURM_UP_TIMEOUT  overall time budget in seconds for all waits (default 90)
set -Eeuo pipefail

HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
readonly HERE
readonly PARTITION=debug          # the name the sweep configs and tests/slurm_cluster.py use
readonly NODE=localhost           # fixed node name: independent of the machine's hostname
readonly CLUSTER=morality         # accounting cluster name (recorded in MariaDB)
readonly CONF_DIR=/etc/slurm
readonly LOG_DIR=/var/log/slurm
readonly MUNGE_LOG=/var/log/munge/munged.log
readonly SLURMCTLD_PID=/run/slurmctld.pid
readonly SLURMD_PID=/run/slurmd.pid
readonly SLURMDBD_PID=/run/slurmdbd.pid
readonly MARIADB_PID=/run/mysqld/mysqld.pid
readonly MUNGED_PID=/run/munge/munged.pid
readonly DEADLINE=$((SECONDS + ${SLURM_UP_TIMEOUT:-90}))

say() { echo "slurm_up [${SECONDS}s]: $*"; }

dump_logs() {
  local f
  for f in "$LOG_DIR"/slurmctld.log "$LOG_DIR"/slurmd.log "$LOG_DIR"/slurmdbd.log \
           "$LOG_DIR"/mariadb.log "$MUNGE_LOG"; do
    [[ -s $f ]] || continue
    echo "----- last lines of $f -----" >&2
    tail -n 25 "$f" >&2
  done
}

die() {
  trap - ERR
  echo "slurm_up: ERROR: $*" >&2
  { timeout 5 sinfo -N -l 2>&1 || true; } | sed 's/^/  sinfo: /' >&2
  dump_logs
  exit 1
}
# Any unexpected failing command also ends with the daemon logs, not with a bare exit code.
trap 'die "command failed (line $LINENO): $BASH_COMMAND"' ERR

[[ $(id -u) == 0 ]] || die "must run as root (munged, mariadbd and the slurm daemons are started here)"
for bin in munged munge unmunge mariadbd mariadb-admin slurmdbd slurmctld slurmd sinfo sacctmgr scontrol; do
  command -v "$bin" >/dev/null || [[ -x /usr/sbin/$bin ]] \
    || die "$bin not found: apt-get install slurm-wlm munge slurmdbd mariadb-server (or: make system-deps)"
done
export PATH=$PATH:/usr/sbin

# alive PID: the process exists and is not a zombie. (PID 1 here reaps orphans lazily, so an
# exited daemon can linger as a zombie, which `kill -0` would still report as present.)
alive() { [[ -r /proc/$1/stat && $(awk '{print $3}' "/proc/$1/stat" 2>/dev/null) != Z ]]; }

# pid_of PIDFILE COMM: print the PID if PIDFILE names a live process whose name is COMM. Checking
# the name protects against a stale PID file whose PID has been reused.
pid_of() {
  local pid
  [[ -s $1 ]] || return 1
  pid=$(tr -dc '0-9' <"$1")
  [[ -n $pid && $(cat "/proc/$pid/comm" 2>/dev/null) == "$2" ]] && alive "$pid" || return 1
  echo "$pid"
}

# wait_for DESCRIPTION CHECK COMMAND...: retry COMMAND every 0.25 s until it succeeds. Die at the
# deadline, or as soon as CHECK (a command, e.g. "daemon_alive slurmd ...") fails, so that a
# daemon that exits at start-up (bad config, port in use) is reported at once, not after the
# whole time budget. Each COMMAND must bound its own run time (a daemon that accepts connections
# but never answers would otherwise stall the loop).
wait_for() {
  local what=$1 check=$2; shift 2
  until "$@" >/dev/null 2>&1; do
    $check || die "$what: the daemon exited during start-up (see its log below)"
    ((SECONDS < DEADLINE)) || die "timed out waiting for $what"
    sleep 0.25
  done
}

# daemon_alive PIDFILE COMM STARTED_AT: false once the daemon we started is gone. The self-
# daemonising slurm daemons and munged write their PID file within about a second: allow 5 s.
daemon_alive() { pid_of "$1" "$2" >/dev/null || ((SECONDS - $3 < 5)); }

munge_ok() { timeout 5 munge -n 2>/dev/null | timeout 5 unmunge >/dev/null 2>&1; }
mariadb_ok() { timeout 5 mariadb-admin --connect-timeout=2 ping >/dev/null 2>&1; }
# sacctmgr talks to slurmdbd (which needs MariaDB), so an answer proves the whole accounting chain.
dbd_ok() { timeout 5 sacctmgr -n -P list cluster format=cluster >/dev/null 2>&1; }
# scontrol ping exits 0 only when the controller answers.
ctld_ok() { timeout 5 scontrol ping >/dev/null 2>&1; }
# slurmctld registers the cluster in slurmdbd by itself once it is connected; until then job
# records are only queued, so wait for the registration before calling the cluster ready.
cluster_registered() { timeout 5 sacctmgr -n -P list cluster format=cluster 2>/dev/null | grep -qx "$CLUSTER"; }
node_state() { timeout 5 sinfo -h -N -n "$NODE" -p "$PARTITION" -o '%t' 2>/dev/null | head -n1; }
# idle/mix/alloc: slurmd is registered and the node takes jobs (a second call may find jobs running).
node_usable() { [[ $(node_state) =~ ^(idle|mix|alloc)$ ]]; }

mkdir -p "$CONF_DIR" "$LOG_DIR" /var/spool/slurmctld /var/spool/slurmd

# ---------------------------------------------------------------------------------------------
# 1. Configuration. Written every time (so that a changed CPU/memory size is picked up) but
#    replaced only when its content differs, so a second call does not disturb running daemons.
# ---------------------------------------------------------------------------------------------
# The CPUs this process may run on. GNU nproc also honours OMP_NUM_THREADS / OMP_THREAD_LIMIT, which a
# caller that pinned its own thread pools (the benchmarks, a sweep worker) has set to 1: that would
# declare a 1-CPU node, so ignore them here.
ncpu=$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)
# 90% of MemTotal: slurmd drains a node whose RealMemory is above the memory it detects, so leave
# a margin (and room for the daemons). Jobs asking for more than this are rejected at submit time.
mem_mb=$(awk '/^MemTotal:/ {print int($2 / 1024 * 0.9)}' /proc/meminfo)

new_conf=$(mktemp)
new_dbd_conf=$(mktemp)
trap 'rm -f "$new_conf" "$new_dbd_conf"' EXIT

cat >"$new_conf" <<EOF
# Written by runners/slurm/slurm_up.sh: single-node cluster for the project's sweeps and tests.
ClusterName=$CLUSTER
# "localhost" is accepted as controller name whatever the machine's hostname is (and even if the
# hostname does not resolve).
SlurmctldHost=localhost
# Everything runs as root: no slurm user, no per-user accounts or associations needed.
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
MpiDefault=none
# No mailer here; without this slurmctld complains about an invalid MailProg at every start.
MailProg=/bin/true
# No cgroups: there is no systemd and no cgroup delegation. linuxproc still tracks (and scancel
# kills) a job's whole process tree.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
# Accounting through slurmdbd + MariaDB. submitit polls job states with sacct: without accounting a
# job that dies without writing its result (os._exit, segfault, OOM kill) stays UNKNOWN forever and
# the sweep hangs.
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=localhost
JobCompType=jobcomp/none
# batch_sched_delay=0: start array tasks at once instead of batching them every 3 s.
SchedulerType=sched/backfill
SchedulerParameters=batch_sched_delay=0
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
# Reject at submit time what this node can never run (e.g. cpus_per_task > $ncpu); without it such
# a job is accepted and pends forever (Reason=PartitionConfig), hanging the sweep.
EnforcePartLimits=ALL
# A node that was DOWN comes back as soon as its slurmd registers with a valid configuration.
ReturnToService=2
# Seconds between SIGTERM and SIGKILL for cancelled or timed-out jobs (default 30): keeps
# slurm_down.sh quick. submitit's own pre-timeout signal (USR2) is independent of this.
KillWait=5
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=$SLURMCTLD_PID
SlurmdPidFile=$SLURMD_PID
SlurmctldLogFile=$LOG_DIR/slurmctld.log
SlurmdLogFile=$LOG_DIR/slurmd.log
# NodeName is fixed to "localhost" (slurmd is started with -N) and addressed by IP, so nothing
# depends on the machine's hostname resolving.
NodeName=$NODE NodeAddr=127.0.0.1 CPUs=$ncpu RealMemory=$mem_mb State=UNKNOWN
PartitionName=$PARTITION Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF

cat >"$new_dbd_conf" <<EOF
# Written by runners/slurm/slurm_up.sh.
AuthType=auth/munge
DbdHost=localhost
SlurmUser=root
LogFile=$LOG_DIR/slurmdbd.log
PidFile=$SLURMDBD_PID
# MariaDB's root logs in by unix_socket authentication and slurmdbd runs as root, so no database
# user, password or grant is needed. "localhost" makes the client use the unix socket (MariaDB is
# started with --skip-networking).
StorageType=accounting_storage/mysql
StorageHost=localhost
StorageUser=root
StorageLoc=slurm_acct_db
EOF

conf_changed=0
install_conf() {  # install_conf NEW DEST: replace DEST only if the content differs
  if ! cmp -s "$1" "$2"; then
    install -m "$3" -o root -g root "$1" "$2"
    conf_changed=1
  fi
}
install_conf "$new_conf" "$CONF_DIR/slurm.conf" 644
# slurmdbd refuses to start unless its config is mode 600 and owned by its SlurmUser.
install_conf "$new_dbd_conf" "$CONF_DIR/slurmdbd.conf" 600

if ((conf_changed)) && { pid_of "$SLURMCTLD_PID" slurmctld || pid_of "$SLURMD_PID" slurmd ||
                         pid_of "$SLURMDBD_PID" slurmdbd; } >/dev/null; then
  # Daemons read their config only at start: restart everything rather than run a mix of old and
  # new settings (e.g. a changed CPU count would drain the node).
  say "configuration changed while the cluster runs: restarting it"
  bash "$HERE/slurm_down.sh"
fi

# ---------------------------------------------------------------------------------------------
# 2. munge: authentication between all slurm daemons and commands.
# ---------------------------------------------------------------------------------------------
if munge_ok; then
  say "munged already running"
else
  # The munge package's postinst creates the key; recreate it only if it is missing.
  [[ -s /etc/munge/munge.key ]] || mungekey --create --keyfile=/etc/munge/munge.key
  # munged refuses to run as root ("PRNG seed dir is insecure") and checks that its key, state
  # and runtime directories belong to the munge user.
  mkdir -p /run/munge /var/lib/munge /var/log/munge
  chown munge:munge /etc/munge/munge.key /run/munge /var/lib/munge /var/log/munge
  chmod 0400 /etc/munge/munge.key
  chmod 0755 /run/munge
  if pid=$(pid_of "$MUNGED_PID" munged); then
    die "munged (pid $pid) runs but does not answer (munge -n | unmunge fails)"
  fi
  # --force: a munged that was killed leaves its socket behind, which otherwise blocks the start.
  # --origin: munged looks the hostname up to stamp credentials; pinning it avoids a lookup of a
  # hostname that may not resolve.
  t0=$SECONDS
  runuser -u munge -- /usr/sbin/munged --force --origin=127.0.0.1
  wait_for "munged" "daemon_alive $MUNGED_PID munged $t0" munge_ok
  say "munged started"
fi

# ---------------------------------------------------------------------------------------------
# 3. MariaDB: storage behind slurmdbd. Unix socket only (no TCP port opened).
# ---------------------------------------------------------------------------------------------
if mariadb_ok; then
  say "MariaDB already running"
else
  if [[ ! -d /var/lib/mysql/mysql ]]; then
    # The mariadb-server postinst normally initialises the data directory; redo it if it is gone.
    say "initialising the MariaDB data directory"
    mariadb-install-db --user=mysql --datadir=/var/lib/mysql --skip-test-db >>"$LOG_DIR/mariadb.log" 2>&1
  fi
  mkdir -p /run/mysqld
  chown mysql:mysql /run/mysqld
  # setsid + redirections: the server must not share this script's session or output pipes, or a
  # caller that reads our output (pytest's subprocess) would wait for it until it exits.
  setsid /usr/sbin/mariadbd --user=mysql --skip-networking --pid-file="$MARIADB_PID" \
    </dev/null >>"$LOG_DIR/mariadb.log" 2>&1 &
  # mariadbd does not daemonise: $! is the server itself (it may take a while to write its PID
  # file, e.g. during crash recovery, so watch the PID directly).
  wait_for "MariaDB" "alive $!" mariadb_ok
  say "MariaDB started"
fi

# ---------------------------------------------------------------------------------------------
# 4. slurmdbd: accounting daemon (sacct, sacctmgr, and job states for submitit).
# ---------------------------------------------------------------------------------------------
if pid_of "$SLURMDBD_PID" slurmdbd >/dev/null; then
  say "slurmdbd already running"
else
  t0=$SECONDS
  /usr/sbin/slurmdbd   # daemonises itself; creates the database schema on its first start
  wait_for "slurmdbd" "daemon_alive $SLURMDBD_PID slurmdbd $t0" dbd_ok
  say "slurmdbd started"
fi
wait_for "slurmdbd to answer sacctmgr" true dbd_ok

# ---------------------------------------------------------------------------------------------
# 5. slurmctld (controller) and slurmd (node daemon).
# ---------------------------------------------------------------------------------------------
if pid_of "$SLURMCTLD_PID" slurmctld >/dev/null; then
  say "slurmctld already running"
else
  # -c: start from a clean state; jobs and node states of an earlier run are discarded, so an
  # old crash cannot leave the node drained. (Job records already in MariaDB are kept.)
  t0=$SECONDS
  /usr/sbin/slurmctld -c
  wait_for "slurmctld" "daemon_alive $SLURMCTLD_PID slurmctld $t0" ctld_ok
  say "slurmctld started"
fi
wait_for "slurmctld to answer" true ctld_ok

if pid_of "$SLURMD_PID" slurmd >/dev/null; then
  say "slurmd already running"
else
  # -N: use the node name from slurm.conf instead of matching the machine's hostname, which may
  # not be "localhost" and may not even resolve (slurmd then loops on getaddrinfo failures).
  /usr/sbin/slurmd -N "$NODE"
  say "slurmd started"
fi
t0=$SECONDS

# ---------------------------------------------------------------------------------------------
# 6. Readiness: the node takes jobs and slurmctld is registered in accounting.
# ---------------------------------------------------------------------------------------------
# (slurmctld keeps showing the node idle for minutes after a slurmd died, so look at slurmd too.)
until pid_of "$SLURMD_PID" slurmd >/dev/null && node_usable; do
  state=$(node_state || true)
  if [[ $state == *drain* || $state == down* ]]; then
    # A node drained by an earlier run (e.g. a memory mismatch) would stay unusable; a resume is
    # harmless when the cause is gone and the state shows up in the failure message otherwise.
    scontrol update NodeName="$NODE" State=RESUME >/dev/null 2>&1 || true
  fi
  daemon_alive "$SLURMD_PID" slurmd "$t0" || die "slurmd exited during start-up (see its log below)"
  ((SECONDS < DEADLINE)) || die "node $NODE not usable (state: ${state:-none})"
  sleep 0.25
done
wait_for "slurmctld to register cluster '$CLUSTER' in slurmdbd" true cluster_registered
pid_of "$SLURMD_PID" slurmd >/dev/null || die "slurmd exited during start-up (see its log below)"

say "ready: partition $PARTITION, node $NODE, $ncpu CPUs, ${mem_mb} MB"
sinfo
