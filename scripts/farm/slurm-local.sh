#!/usr/bin/env bash
# A single-node Slurm on this machine, to try the farm templates for real (docs/farm.md).
#   scripts/farm/slurm-local.sh start    install slurm-wlm + munge if missing, write a one-node
#                                        slurm.conf, start munged, slurmctld and slurmd
#   scripts/farm/slurm-local.sh stop     stop the three daemons this script started
#   scripts/farm/slurm-local.sh status   sinfo
# Root (or sudo) needed. Opt-in: never part of .ci/run. Works without systemd (containers): the
# daemons are started directly and their pids kept in /run/frostvdb-slurm/.
set -euo pipefail
action="${1:-start}"
state=/run/frostvdb-slurm
sudo_cmd=""
[ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"

install_packages() {
  local missing=()
  for p in slurm-wlm munge; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    echo "slurm-local: installing ${missing[*]}" >&2
    $sudo_cmd apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
  fi
}

write_config() {
  local host cpus mem
  host="$(hostname -s)"
  cpus="$(nproc)"
  mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))
  $sudo_cmd mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm "$state"
  $sudo_cmd chown slurm:slurm /var/spool/slurmctld /var/log/slurm 2>/dev/null || true
  $sudo_cmd tee /etc/slurm/slurm.conf >/dev/null <<CONF
# written by frostvdb scripts/farm/slurm-local.sh: one node, no accounting
ClusterName=frostvdb-local
SlurmctldHost=${host}
SlurmUser=slurm
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=${state}/slurmctld.pid
SlurmdPidFile=${state}/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
NodeName=${host} CPUs=${cpus} RealMemory=${mem} State=UNKNOWN
PartitionName=local Nodes=${host} Default=YES MaxTime=INFINITE State=UP
CONF
  # cgroup-free: containers rarely delegate cgroups
  echo "IgnoreSystemd=yes" | $sudo_cmd tee /etc/slurm/cgroup.conf >/dev/null
}

start_munge() {
  if [ ! -s /etc/munge/munge.key ]; then
    $sudo_cmd mkdir -p /etc/munge
    $sudo_cmd dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
  fi
  $sudo_cmd chown munge:munge /etc/munge/munge.key 2>/dev/null || true
  $sudo_cmd chmod 400 /etc/munge/munge.key
  $sudo_cmd mkdir -p /run/munge /var/log/munge /var/lib/munge
  $sudo_cmd chown munge:munge /run/munge /var/log/munge /var/lib/munge 2>/dev/null || true
  if ! munge -n >/dev/null 2>&1; then
    if [ "$(id -u)" -eq 0 ]; then runuser -u munge -- munged; else sudo -u munge munged; fi
  fi
  munge -n | unmunge >/dev/null
}

case "$action" in
start)
  install_packages
  write_config
  start_munge
  pgrep -F "$state/slurmctld.pid" >/dev/null 2>&1 || $sudo_cmd slurmctld
  sleep 1
  pgrep -F "$state/slurmd.pid" >/dev/null 2>&1 || $sudo_cmd slurmd
  for _ in $(seq 30); do
    sinfo -h -o %T 2>/dev/null | grep -qE "idle|mixed|alloc" && break
    sleep 1
  done
  $sudo_cmd scontrol update nodename="$(hostname -s)" state=resume 2>/dev/null || true
  sinfo
  ;;
stop)
  for d in slurmd slurmctld; do
    [ -f "$state/$d.pid" ] && $sudo_cmd kill "$(cat "$state/$d.pid")" 2>/dev/null || true
  done
  ;;
status)
  sinfo
  ;;
*)
  echo "usage: $0 start|stop|status" >&2
  exit 2
  ;;
esac
