# Sourced by scripts/test and scripts/soak: the tests' scratch files (run stores, reports, the private
# PostgreSQL, the browser's profile: everything under TMPDIR) in memory, on /dev/shm, when it is a tmpfs with
# room to spare and TMPDIR is not set already.
# Why: this host's disk holds an fsync for tens of seconds while it writes back what was written before it (seen
# here: 52 s, the write-back of a fresh venv), and the suite makes thousands of durable commits; each would wait
# behind it, and every wall-clock bound of a test with it. The station's own tolerance of a stalled commit is
# tested by itself (tests/controller/test_driver.py, tests/ur/test_robot_interface.py: a status callback that
# blocks past the program's timeout). TEST_SCRATCH=disk keeps the scratch on the disk.
SCRATCH=""
scratch_dir() {
  SCRATCH=""
  [ "${TEST_SCRATCH:-memory}" = disk ] && return 0
  [ -n "${TMPDIR:-}" ] && return 0
  [ -d /dev/shm ] && [ -w /dev/shm ] || return 0
  [ "$(stat -f -c %T /dev/shm 2>/dev/null)" = tmpfs ] || return 0
  local free_kb
  free_kb="$(df -Pk /dev/shm | awk 'NR == 2 {print $4}')"
  [ "${free_kb:-0}" -ge $((4 * 1024 * 1024)) ] || return 0
  SCRATCH="$(mktemp -d /dev/shm/station-tests.XXXXXX)"
  chmod 1777 "$SCRATCH"  # as /tmp: the private PostgreSQL runs as the postgres user and makes its folder here
  export TMPDIR="$SCRATCH"
}
# scratch_done RC: remove the scratch of a run that passed; keep (and name) the one of a run that failed
scratch_done() {
  [ -n "$SCRATCH" ] || return 0
  if [ "${1:-0}" -eq 0 ]; then
    rm -rf "$SCRATCH"
  else
    echo "scratch of this run kept in $SCRATCH (tmp_path of each test; remove it when done)" >&2
  fi
  unset TMPDIR
  SCRATCH=""
}
