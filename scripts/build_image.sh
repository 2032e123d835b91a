#!/usr/bin/env bash
# Builds the container image of surfacer-server and the surfacer CLI from deploy/Dockerfile (multi-stage, Debian 12;
# its build stage runs scripts/setup.sh, like a build by hand). Uses docker, else podman, else buildah.
# Usage: scripts/build_image.sh [TAG] [extra build flags, e.g. --no-cache or --platform linux/arm64]
#   TAG      default: the project version in CMakeLists.txt (what deploy/ refers to, e.g. surfacer:0.1.0)
# Environment: SURFACER_IMAGE (default surfacer), SURFACER_ENGINE (docker, podman or buildah: skip the search).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

version=$(sed -n 's/^project(surfacer VERSION \([0-9.]*\).*/\1/p' CMakeLists.txt)
tag=$version
if [ $# -gt 0 ] && [[ $1 != -* ]]; then
  tag=$1
  shift
fi
[ -n "$tag" ] || { echo "build_image: no version in CMakeLists.txt's project(); give the tag: $0 TAG" >&2; exit 2; }
image="${SURFACER_IMAGE:-surfacer}:$tag"

# An engine counts only when it can build now: the docker CLI without a reachable daemon does not.
usable() {
  case $1 in
    docker) command -v docker >/dev/null && docker info >/dev/null 2>&1 ;;
    podman) command -v podman >/dev/null && podman info >/dev/null 2>&1 ;;
    buildah) command -v buildah >/dev/null ;;
    *) return 1 ;;
  esac
}
if [ -n "${SURFACER_ENGINE:-}" ]; then
  engines=("$SURFACER_ENGINE")
else
  engines=(docker podman buildah)
fi
engine=""
for e in "${engines[@]}"; do
  if usable "$e"; then engine=$e; break; fi
done
if [ -z "$engine" ]; then
  {
    echo "build_image: no usable container engine (tried: ${engines[*]})."
    if [[ " ${engines[*]} " == *" docker "* ]] && command -v docker >/dev/null; then
      why=$(docker info 2>&1 | grep -m1 -i 'error\|cannot' || true)
      echo "  docker is installed but its daemon does not answer: ${why:-no answer}"
      echo "  Start it (sudo systemctl start docker) or use DOCKER_HOST for a remote one."
    fi
    echo "  Install one: sudo apt-get install docker.io (or podman, or buildah), or build on a machine that has one:"
    echo "    docker build -f deploy/Dockerfile -t $image ."
  } >&2
  exit 3
fi

echo "build_image: $engine building $image from deploy/Dockerfile" >&2
case $engine in
  docker | podman) "$engine" build -f deploy/Dockerfile -t "$image" "$@" . ;;
  buildah) buildah build -f deploy/Dockerfile -t "$image" "$@" . ;;
esac
echo "build_image: built $image. Next: deploy/make-dev-secrets.sh && docker compose -f deploy/docker-compose.yml up -d," \
  "or push it and kubectl apply -k deploy/k8s (see README, Deploying)" >&2
