#!/usr/bin/env bash
# Runs vtkillum's ParaView plugin tests (tests/plugin) against a newer ParaView than the
# host's, in a Debian chroot, on a Debian (12) host, as root:
#
#   .ci/paraview-chroot.sh forky  [PYTEST ARGS...]   # ParaView 6.1.1, VTK 9.6.2, Python 3.14
#   .ci/paraview-chroot.sh trixie [PYTEST ARGS...]   # ParaView 5.13.2, VTK 9.3, Python 3.13
#
#   .ci/paraview-chroot.sh SUITE --run COMMAND...     # any command, e.g. python tests/plugin/...
#
# PYTEST ARGS default to `-q -ra tests/plugin`; --run runs COMMAND instead of pytest, in the
# same place and environment (the chroot's copy of the checkout, /root/vtkillum, which is
# replaced on the next run: copy what it writes out of $VTKILLUM_CI_CACHE/SUITE/root/vtkillum
# first). The chroot is cached in
# $VTKILLUM_CI_CACHE/SUITE (default /var/cache/vtkillum-ci/SUITE, ~4.5 GB):
#   * absent (or a build that did not finish): built with debootstrap + apt (Debian's
#     paraview, python3-paraview, xvfb, Mesa), then a virtual environment with
#     vtkillum[test] (pip, from PyPI): measured on 2 cores 3 min (forky) on a quiet machine,
#     7-11 min at load 10;
#   * present: only refreshed: this working tree (tracked and untracked, not ignored
#     files) replaces the chroot's copy in /root/vtkillum and is installed again into the
#     chroot's venv (/opt/vtkillum-venv, kept between runs); `apt-get upgrade` is not run
#     (set VTKILLUM_CI_UPGRADE=1 to run it).
# Rebuild from scratch: rm -rf /var/cache/vtkillum-ci/SUITE (nothing is mounted there
# outside a run: the mounts live in a private mount namespace of this script).
#
# Inside the chroot the tests run
#   * in their own network namespace (`unshare -n`): `xvfb-run -a` there only sees the
#     chroot's /tmp lock files while X's abstract sockets are shared per network namespace,
#     so a display number in use on the host would collide ("bad X server connection");
#   * with VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow for the PyPI VTK in pytest itself
#     (forky's Mesa has no OSMesa, and that VTK segfaulted rendering through Xvfb there);
#     pvbatch and the GUI run under the tests' own xvfb-run (do not wrap pytest in another
#     xvfb-run: nested xvfb-run fails).
# Variables VTKILLUM_* of the caller are passed to the tests (e.g. VTKILLUM_PARAVIEW_DISPLAY).
set -euo pipefail

SUITE=${1:?usage: $0 forky|trixie [pytest args...]}
shift
case "$SUITE" in
  forky) PV="ParaView 6.1" ;;
  trixie) PV="ParaView 5.13" ;;
  *) PV="ParaView of Debian $SUITE" ;;
esac
REPO=$(cd "$(dirname "$0")/.." && pwd)
CACHE=${VTKILLUM_CI_CACHE:-/var/cache/vtkillum-ci}
DIR=$CACHE/$SUITE
VENV=/opt/vtkillum-venv
APT_OPTS="-o DPkg::Lock::Timeout=600 -q"
export DEBIAN_FRONTEND=noninteractive

fail() { echo "paraview-chroot.sh ($SUITE, $PV): FAILED: $*" >&2; exit 1; }
[ "$(id -u)" = 0 ] || fail "needs root (debootstrap, chroot, mount)"

# Mounts are made in a private mount namespace: they vanish with this script, whatever
# happens to it, and the host never sees them (so removing the cache cannot reach /dev).
if [ -z "${VTKILLUM_CI_NS:-}" ]; then
  command -v unshare >/dev/null || fail "unshare (util-linux) not found"
  VTKILLUM_CI_NS=1 exec unshare -m --propagation private "$0" "$SUITE" "$@"
fi

mkdir -p "$CACHE"
exec 9>"$CACHE/$SUITE.lock"
flock -w 3600 9 || fail "another run holds $CACHE/$SUITE.lock for more than an hour"

t0=$(date +%s)
stage() { echo "== paraview-chroot.sh $SUITE: $* ($(( $(date +%s) - t0 )) s)"; }

mounted() { awk -v d="$DIR" 'index($2, d "/") == 1 {print $2}' /proc/self/mounts | sort -r; }
cleanup() {
  local m
  for m in $(mounted); do umount "$m" 2>/dev/null || umount -l "$m" 2>/dev/null || true; done
}
trap cleanup EXIT
trap 'fail "interrupted"' INT TERM

# 0. host tools
if ! command -v debootstrap >/dev/null; then
  stage "installing debootstrap on the host"
  apt-get $APT_OPTS update
  apt-get $APT_OPTS install -y debootstrap || fail "apt-get install debootstrap"
fi

# 1. base system (once; .vtkillum-ci-base marks a finished debootstrap, .vtkillum-ci-system
#    the packages below installed)
if [ ! -e "$DIR/.vtkillum-ci-base" ]; then
  if [ -e "$DIR" ]; then
    stage "removing the unfinished debootstrap in $DIR"
    cleanup
    [ -z "$(mounted)" ] || fail "cannot unmount $(mounted | tr '\n' ' ')"
    rm -rf --one-file-system "$DIR"
  fi
  MIRROR=$(awk '/^URIs:/{print $2; exit}' /etc/apt/sources.list.d/debian.sources 2>/dev/null || true)
  [ -n "$MIRROR" ] || MIRROR=$(awk '$1=="deb"{print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)
  [ -n "$MIRROR" ] || MIRROR=http://deb.debian.org/debian
  stage "debootstrap $SUITE from $MIRROR into $DIR"
  # bookworm's debootstrap has no script for forky: the sid script works for any suite.
  debootstrap --variant=minbase --include=ca-certificates "$SUITE" "$DIR" "$MIRROR" \
    /usr/share/debootstrap/scripts/sid || fail "debootstrap (see above)"
  touch "$DIR/.vtkillum-ci-base"
fi
# A frozen mirror copy may be past its Release file's Valid-Until; harmless elsewhere.
echo 'Acquire::Check-Valid-Until "false";' > "$DIR/etc/apt/apt.conf.d/99no-check-valid-until"

# 2. mounts (private to this script), X socket directory, DNS, CA bundle for pip
for d in proc sys dev dev/pts dev/shm; do
  mountpoint -q "$DIR/$d" || mount --bind "/$d" "$DIR/$d" || fail "mount --bind /$d $DIR/$d"
done
mkdir -p "$DIR/tmp/.X11-unix"; chmod 1777 "$DIR/tmp" "$DIR/tmp/.X11-unix"
cp /etc/resolv.conf "$DIR/etc/resolv.conf"
# Where HTTPS goes through an intercepting proxy, pip needs the host's CA bundle.
cp /etc/ssl/certs/ca-certificates.crt "$DIR/etc/ssl/certs/host-ca-bundle.crt"

CH() {  # a command in the chroot, with a clean environment
  chroot "$DIR" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 \
    DEBIAN_FRONTEND=noninteractive PIP_CERT=/etc/ssl/certs/host-ca-bundle.crt \
    PIP_DISABLE_PIP_VERSION_CHECK=1 "$@"
}

if [ ! -e "$DIR/.vtkillum-ci-system" ]; then
  # ~700 packages, ~700 MB download. libegl1/libegl-mesa0: EGL for the PyPI VTK in pytest.
  stage "apt-get install paraview python3-paraview xvfb (chroot)"
  CH apt-get $APT_OPTS update || fail "apt-get update in the chroot"
  CH apt-get $APT_OPTS install -y paraview python3-paraview \
    xvfb xauth python3-venv libgl1-mesa-dri libglx-mesa0 libegl1 libegl-mesa0 \
    || fail "apt-get install in the chroot"
  CH apt-get clean
  touch "$DIR/.vtkillum-ci-system"
elif [ -n "${VTKILLUM_CI_UPGRADE:-}" ]; then
  stage "apt-get upgrade (chroot)"
  CH bash -c "apt-get $APT_OPTS update && apt-get $APT_OPTS upgrade -y && apt-get clean" \
    || fail "apt-get upgrade in the chroot"
fi

# 3. this working tree -> /root/vtkillum (replaced, so no stale file survives)
stage "copying the working tree $REPO into the chroot"
rm -rf --one-file-system "$DIR/root/vtkillum"
mkdir -p "$DIR/root/vtkillum"
if git -C "$REPO" rev-parse --git-dir >/dev/null 2>&1; then
  # tracked + untracked files that git does not ignore, as they are on disk now
  (cd "$REPO" && git ls-files -z --cached --others --exclude-standard \
     | while IFS= read -r -d '' f; do [ -e "$f" ] && printf '%s\0' "$f"; done \
     | tar --null -T - -cf -) | tar -xf - -C "$DIR/root/vtkillum" || fail "copying the checkout"
else
  (cd "$REPO" && tar --exclude=./.venv --exclude=./.git -cf - .) \
    | tar -xf - -C "$DIR/root/vtkillum" || fail "copying the checkout"
fi

# 4. the venv (kept) with vtkillum[test] installed again from the copy
stage "pip install vtkillum[test] into $VENV (chroot)"
CH bash -c "set -e; [ -x $VENV/bin/python ] || python3 -m venv $VENV
  $VENV/bin/python -m pip install -q --upgrade pip
  cd /root/vtkillum && $VENV/bin/python -m pip install -q '.[test]'" \
  || fail "pip install in the chroot (network? see above)"
CH bash -c "pvpython --version 2>/dev/null; $VENV/bin/python -c 'import sys, vtk; \
print(\"python\", sys.version.split()[0], \"pip vtk\", vtk.vtkVersion.GetVTKVersion())'" || true

# 5. the tests, in their own network namespace
[ $# -gt 0 ] || set -- -q -ra tests/plugin
if [ "$1" = --run ]; then
  shift; [ $# -gt 0 ] || fail "--run needs a command"
else
  set -- python -m pytest "$@"
fi
stage "$* (chroot, $PV, in its own network namespace)"
passthrough=()
while IFS='=' read -r name value; do
  case "$name" in VTKILLUM_CI_*) ;; VTKILLUM_*) passthrough+=("$name=$value") ;; esac
done < <(env)
status=0
unshare -n sh -c 'ip link set lo up 2>/dev/null; exec "$@"' sh \
  chroot "$DIR" /usr/bin/env -i PATH=$VENV/bin:/usr/sbin:/usr/bin:/sbin:/bin HOME=/root \
  LANG=C.UTF-8 VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow "${passthrough[@]}" \
  bash -c 'cd /root/vtkillum && exec "$@"' command "$@" || status=$?
exit "$status"   # nothing printed after pytest: its summary line ends the output
