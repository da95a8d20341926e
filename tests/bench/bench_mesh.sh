#!/usr/bin/env bash
# bench_mesh.sh BUILD - load + weld + metrics on every shared mesh and a
# generated 1M-facet torus; `cat` of the same file as the disk-speed reference.
set -u
build=${1:-build/rel}
meshes=()
[ -d ../shared/meshes ] && meshes=(../shared/meshes/bunny00.stl ../shared/meshes/armadillo.stl)
"$build/bench/bench_mesh" "${meshes[@]}"
"$build/bench/bench_mesh"
