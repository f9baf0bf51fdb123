#!/usr/bin/env bash
# The plugin tests (tests/plugin) on ParaView 5.13.2 (Debian trixie: VTK 9.3, Python 3.13),
# in a chroot cached in /var/cache/vtkillum-ci/trixie. Not part of .ci/run (which covers the
# host's ParaView 5.11 and ParaView 6.1): run it, as root on a Debian 12 machine, before
# resolving an issue that touches the ParaView plugin:
#
#   sudo .ci/paraview-trixie.sh                      # all of tests/plugin (6-13 min cached)
#   sudo .ci/paraview-trixie.sh -q tests/plugin/test_render.py
#
# The first run builds the chroot (4-8 min on 2 cores, ~4.5 GB); see .ci/paraview-chroot.sh.
exec "$(dirname "$0")/paraview-chroot.sh" trixie "$@"
