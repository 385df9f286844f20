#!/usr/bin/env bash
# Build LAMMPS from source for opalflow: KOKKOS (OpenMP backend, or CUDA with --cuda ARCH), OPENMP, BPM, GRANULAR,
# MANYBODY and what the decks use beside them, as a shared library with its Python module, MPI from the mpich
# wheel of this virtual environment.  opalflow runs it when pointed at the prefix:
#
#     bash scripts/build-lammps.sh --source ~/lammps                 # a LAMMPS checkout (git clone -b stable ...)
#     export OPALFLOW_LAMMPS=$(bash scripts/build-lammps.sh --source ~/lammps --print-prefix)
#     python -m opalflow info                                          # which LAMMPS, what it has
#
# Options: --source DIR (the checkout: DIR/cmake/CMakeLists.txt), --prefix DIR (default: a folder of
# ~/.cache/opalflow/lammps named by the configuration's hash: one build per source and options, reused),
# --cuda ARCH (Kokkos_ARCH_<ARCH>, e.g. HOPPER90 for an H200; nvcc must be on PATH), --jobs N (default: all
# cores), --print-prefix (say where the build is or would be, build nothing).
# Needs: a C++17 compiler, and cmake and ninja (from PyPI: pip install cmake ninja, done here when missing).
set -euo pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
py=${PYTHON:-$here/.venv/bin/python}
[ -x "$py" ] || py=$(command -v python3)
venv=$(dirname "$(dirname "$py")")
source_dir="" prefix="" cuda="" jobs=$(nproc) print_prefix=0
while [ $# -gt 0 ]; do
  case "$1" in
    --source) source_dir=$(cd "$2" && pwd); shift 2 ;;
    --prefix) prefix=$2; shift 2 ;;
    --cuda) cuda=$2; shift 2 ;;
    --jobs) jobs=$2; shift 2 ;;
    --print-prefix) print_prefix=1; shift ;;
    *) echo "error: unknown option $1 (see the head of $0)" >&2; exit 2 ;;
  esac
done
if [ -z "$source_dir" ] || [ ! -f "$source_dir/cmake/CMakeLists.txt" ]; then
  echo "error: --source = '${source_dir}': must be a LAMMPS checkout holding cmake/CMakeLists.txt" >&2
  exit 2
fi
[[ "$cuda" =~ ^[A-Z0-9_]*$ ]] || { echo "error: --cuda = '$cuda': must be a Kokkos architecture name (e.g. HOPPER90)" >&2; exit 2; }

# the packages: the accelerators, and every package a deck of opalflow's uses (BPM: bpm/sphere, bpm/rotational;
# GRANULAR: granular pair styles and fix wall/gran; MANYBODY: tersoff; MOLECULE: bonds; EXTRA-PAIR: the packing's
# harmonic/cut; EXTRA-FIX, EXTRA-COMPUTE, MISC: the fixes and computes of the compression and stability decks)
packages=(KOKKOS OPENMP PYTHON BPM GRANULAR MANYBODY MOLECULE EXTRA-PAIR EXTRA-FIX EXTRA-COMPUTE MISC)
options=(-D BUILD_SHARED_LIBS=on -D LAMMPS_EXCEPTIONS=on -D BUILD_MPI=on -D BUILD_OMP=on
         -D CMAKE_BUILD_TYPE=Release "-D CMAKE_CXX_FLAGS_RELEASE=-O2 -DNDEBUG"
         -D MPI_C_COMPILER="$venv/bin/mpicc" -D MPI_CXX_COMPILER="$venv/bin/mpicxx"
         -D Kokkos_ENABLE_SERIAL=on -D Kokkos_ENABLE_OPENMP=on)
for p in "${packages[@]}"; do options+=(-D "PKG_$p=on"); done
if [ -n "$cuda" ]; then
  options+=(-D Kokkos_ENABLE_CUDA=on -D "Kokkos_ARCH_$cuda=on"
            -D CMAKE_CXX_COMPILER="$source_dir/lib/kokkos/bin/nvcc_wrapper")
fi

version=$(sed -n 's/^#define LAMMPS_VERSION "\(.*\)"/\1/p' "$source_dir/src/version.h")
commit=$(git -C "$source_dir" rev-parse HEAD 2>/dev/null || echo "$version")
key=$(printf '%s\n' "$commit" "$version" "${options[@]}" | sha256sum | cut -c1-16)
prefix=${prefix:-${XDG_CACHE_HOME:-$HOME/.cache}/opalflow/lammps/$key}
if [ "$print_prefix" = 1 ]; then echo "$prefix"; exit 0; fi
if [ -f "$prefix/build.json" ] && grep -q "\"key\": \"$key\"" "$prefix/build.json"; then
  echo "LAMMPS $version already built with this configuration: $prefix" >&2
  echo "$prefix"
  exit 0
fi

command -v cmake >/dev/null && command -v ninja >/dev/null || "$py" -m pip install -q cmake ninja
export PATH="$venv/bin:$PATH"
build="$prefix/build"
mkdir -p "$build"
start=$(date +%s)
cmake -S "$source_dir/cmake" -B "$build" -G Ninja -D CMAKE_INSTALL_PREFIX="$prefix" \
      -D CMAKE_INSTALL_RPATH="$prefix/lib;$venv/lib" -D CMAKE_BUILD_WITH_INSTALL_RPATH=on "${options[@]}" \
      >"$prefix/cmake.log"
ninja -C "$build" -j "$jobs" lmp lammps > "$prefix/ninja.log" || { tail -30 "$prefix/ninja.log" >&2; exit 1; }
# the library, lmp (its run path: $prefix/lib and the venv's MPI, set at the link) and the Python module with
# the library beside it, where the module looks first; no "install" target (it wants the manual pages)
rm -rf "$prefix/python" "$prefix/bin" "$prefix/lib"
mkdir -p "$prefix/python" "$prefix/bin" "$prefix/lib"
cp -P "$build"/liblammps.so* "$prefix/lib/"
cp "$build/lmp" "$prefix/bin/"
cp -r "$source_dir/python/lammps" "$prefix/python/"
cp -P "$build"/liblammps.so* "$prefix/python/lammps/"
seconds=$(( $(date +%s) - start ))
size=$(du -sm "$prefix" | cut -f1)
printf '{"key": "%s", "version": "%s", "commit": "%s", "packages": "%s", "cuda": "%s", "jobs": %s, "build_s": %s, "size_MiB": %s}\n' \
  "$key" "$version" "$commit" "${packages[*]}" "$cuda" "$jobs" "$seconds" "$size" > "$prefix/build.json"
rm -rf "$build"
echo "built LAMMPS $version in ${seconds} s (${size} MiB): $prefix" >&2
echo "$prefix"
