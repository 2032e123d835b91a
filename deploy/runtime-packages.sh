#!/usr/bin/env bash
# Prints, one per line, the Debian packages that provide the shared libraries the given binaries load (ldd, then
# dpkg -S), so the runtime image installs exactly what the build produced needs, and a new dependency (SQLite, ...)
# needs no edit here. Used by the build stage of deploy/Dockerfile; runs on any Debian 12 with the binaries built.
# Usage: deploy/runtime-packages.sh BINARY...
# Exit 2 when a library is missing ("not found" by ldd) or belongs to no Debian package (e.g. built into
# /usr/local/lib), naming it: the runtime stage could not install it.
set -euo pipefail

if [ $# -eq 0 ]; then
  echo "usage: $0 BINARY... (e.g. build/server/surfacer-server build/client/surfacer)" >&2
  exit 2
fi

# candidates PATH: the path as ldd prints it, its real path, and the other side of the /usr merge for both (Debian 12
# packages list /lib/x86_64-linux-gnu/..., which is /usr/lib/x86_64-linux-gnu/...), one per line, in that order.
candidates() {
  local real c
  real=$(readlink -f -- "$1")
  printf '%s\n' "$1" "$real"
  for c in "$1" "$real"; do
    case $c in
      /usr/lib/* | /usr/lib64/*) echo "${c#/usr}" ;;
      /lib/* | /lib64/*) echo "/usr$c" ;;
    esac
  done
}

declare -A libs=() # library path -> the binary that needs it
errors=0
for bin in "$@"; do
  if [ ! -f "$bin" ] || [ ! -x "$bin" ]; then
    echo "runtime-packages: $bin is not an executable file; build it first" >&2
    exit 2
  fi
  ldd_out=$(ldd -- "$bin") || {
    echo "runtime-packages: ldd failed on $bin (not a dynamic executable?)" >&2
    exit 2
  }
  while read -r line; do
    case $line in
      *"=> not found"*)
        echo "runtime-packages: $bin needs ${line%% *}, which is not installed here" >&2
        errors=1
        continue
        ;;
      *"=> /"*) lib=${line#*=> } ;;
      /*) lib=$line ;;
      *) continue ;; # linux-vdso.so.1 and other virtual objects
    esac
    libs[${lib%% (0x*}]=$bin
  done <<<"$ldd_out"
done
[ "$errors" -eq 0 ] || exit 2

# One dpkg-query call for every candidate path (it scans the whole file database once per call).
declare -A owner_of=() # path -> package
all_candidates=()
for lib in "${!libs[@]}"; do
  mapfile -t -O "${#all_candidates[@]}" all_candidates < <(candidates "$lib")
done
while IFS= read -r line; do
  # "libgrpc++1.51:amd64: /lib/x86_64-linux-gnu/libgrpc++.so.1.51"; "a, b: /path" when several packages list it
  [[ $line == *": /"* ]] || continue
  path=/${line#*: /}
  pkg=${line%%: /*}
  pkg=${pkg%%, *}
  owner_of[$path]=${pkg%%:*}
done < <(dpkg-query -S -- "${all_candidates[@]}" 2>/dev/null || true)

declare -A packages=()
for lib in "${!libs[@]}"; do
  pkg=""
  while IFS= read -r c; do
    if [ -n "${owner_of[$c]:-}" ]; then
      pkg=${owner_of[$c]}
      break
    fi
  done < <(candidates "$lib")
  if [ -n "$pkg" ]; then
    packages[$pkg]=1
  else
    echo "runtime-packages: $lib (needed by ${libs[$lib]}) belongs to no Debian package; install it from Debian" \
      "or link it statically" >&2
    errors=1
  fi
done
[ "$errors" -eq 0 ] || exit 2
printf '%s\n' "${!packages[@]}" | sort
