#!/usr/bin/env bash
# A real one-node SLURM on this machine, for trying opalflow's SLURM executor and for its tests.
#
#   bash scripts/local-slurm.sh start     # install (Debian: slurmctld slurmd munge) and start it
#   bash scripts/local-slurm.sh status    # sinfo
#   bash scripts/local-slurm.sh stop      # stop the daemons (the state folder is kept)
#
# Runs as root without systemd or cgroups (containers, CI): processes are tracked by
# proctrack/linuxproc, no task plugin, no accounting.  One node named after this machine with all
# its cores; partition "debug"; state and logs under $OPALFLOW_SLURM_DIR (default /var/tmp/opalflow-slurm).
# Exit 2 with one line where it cannot run (not root, no apt-get and no SLURM).
set -euo pipefail
STATE=${OPALFLOW_SLURM_DIR:-/var/tmp/opalflow-slurm}
CONF=/etc/slurm/slurm.conf
say() { echo "local-slurm: $*" >&2; }

install_packages() {
  if command -v slurmctld > /dev/null && command -v slurmd > /dev/null && command -v munged > /dev/null \
     && command -v sbatch > /dev/null; then
    return
  fi
  if ! command -v apt-get > /dev/null; then
    say "cannot install SLURM: no apt-get here (install slurmctld, slurmd, munge and slurm-client yourself)"; exit 2
  fi
  say "installing slurmctld slurmd slurm-client munge (Debian)"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurmctld slurmd slurm-client munge > /dev/null
}

write_config() {
  local host cpus mem
  host=$(hostname -s)
  cpus=$(getconf _NPROCESSORS_ONLN)   # not nproc: it honours OMP_NUM_THREADS (1 inside a test run)
  mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))
  mkdir -p "$STATE/ctld" "$STATE/d" /etc/slurm
  chown slurm:slurm "$STATE/ctld" 2> /dev/null || true
  cat > "$CONF" <<EOF
# written by opalflow scripts/local-slurm.sh: one node, no systemd, no cgroups
ClusterName=opalflow
SlurmctldHost=$host
SlurmUser=root
SlurmctldPort=6817
SlurmdPort=6818
AuthType=auth/munge
# a job credential lives 10 s (default 120): SLURM holds a requeued job that long before it starts it
# again (the node refuses the old credential until then), so a time-limited test requeues in seconds
AuthInfo=cred_expire=10
StateSaveLocation=$STATE/ctld
SlurmdSpoolDir=$STATE/d
SlurmctldPidFile=$STATE/slurmctld.pid
SlurmdPidFile=$STATE/slurmd.pid
SlurmctldLogFile=$STATE/slurmctld.log
SlurmdLogFile=$STATE/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
DefMemPerCPU=2048
SchedulerType=sched/backfill
SchedulerParameters=sched_interval=2,bf_interval=2
MpiDefault=none
ReturnToService=2
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
MinJobAge=300
KillWait=10
Waittime=0
MaxArraySize=10001
# time limits are checked every 15 s (a job gets its signal within that of the time asked)
OverTimeLimit=0
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
EOF
}

start_munge() {
  if pgrep -x munged > /dev/null; then return; fi
  if [ ! -s /etc/munge/munge.key ]; then
    dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2> /dev/null
  fi
  chown munge:munge /etc/munge/munge.key
  chmod 400 /etc/munge/munge.key
  mkdir -p /run/munge /var/log/munge /var/lib/munge
  chown munge:munge /run/munge /var/log/munge /var/lib/munge
  su -s /bin/sh munge -c /usr/sbin/munged 9>&-
}

start() {
  if [ "$(id -u)" != 0 ]; then say "must run as root (it starts munged, slurmctld and slurmd)"; exit 2; fi
  # one start at a time: two test workers starting it together raced for munged's socket (the second
  # one's munged failed on its lock and that worker's SLURM tests were skipped); the second waits here and
  # then finds the daemons running
  exec 9> /run/lock/opalflow-local-slurm.lock
  flock 9
  install_packages
  write_config
  start_munge
  # (the daemons do not inherit the lock's descriptor: they would hold it for good)
  pgrep -x slurmctld > /dev/null || (slurmctld -D > "$STATE/slurmctld.out" 2>&1 9>&- &)
  pgrep -x slurmd > /dev/null || (slurmd -D > "$STATE/slurmd.out" 2>&1 9>&- &)
  for _ in $(seq 1 60); do
    if sinfo -h -o '%t' 2> /dev/null | grep -qE '^(idle|mix|alloc)'; then
      scontrol update nodename="$(hostname -s)" state=resume > /dev/null 2>&1 || true
      say "up: $(sinfo -h -o '%P %D node(s) %c CPUs %t')"
      return
    fi
    sleep 1
  done
  say "did not come up in 60 s; logs in $STATE"; tail -n 5 "$STATE/slurmctld.log" "$STATE/slurmd.log" >&2 || true
  exit 1
}

wait_gone() {   # until no process of that name is left (a dying daemon still matches pgrep)
  for _ in $(seq 1 30); do pgrep -x "$1" > /dev/null || return 0; sleep 0.5; done
  pkill -9 -x "$1" 2> /dev/null || true
}

stop() {
  pkill -x slurmd 2> /dev/null || true
  pkill -x slurmctld 2> /dev/null || true
  wait_gone slurmd
  wait_gone slurmctld
  say "stopped (state kept in $STATE)"
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  restart-controller)   # the fault test: slurmctld dies and comes back; jobs keep running on slurmd
    pkill -x slurmctld 2> /dev/null || true; wait_gone slurmctld; sleep "${2:-5}"; (slurmctld -D > "$STATE/slurmctld.out" 2>&1 &)
    for _ in $(seq 1 30); do sinfo > /dev/null 2>&1 && break; sleep 1; done ;;
  status) sinfo ;;
  *) echo "usage: bash scripts/local-slurm.sh start|stop|status|restart-controller [seconds]" >&2; exit 2 ;;
esac
