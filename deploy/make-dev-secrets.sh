#!/usr/bin/env bash
# Makes throw-away secrets for a test deployment (docker compose, a test cluster) with openssl, into DIR
# (default deploy/secrets/, ignored by git):
#   ca.crt, ca.key      a self-signed CA (10 days)
#   tls.crt, tls.key    a server certificate from that CA (10 days) for localhost, 127.0.0.1, surfacer-1..3 (compose),
#                       surfacer-headless.surfacer.svc.cluster.local and surfacer.surfacer.svc.cluster.local (k8s),
#                       plus every NAME given
#   tokens              one token of tenant "dev" (for --tokens-file), and client-token (for the CLI's --token-file)
# Existing files are kept unless --force. Not for production: tls.key and tokens are readable by everyone (docker
# compose bind-mounts file secrets with their host permissions, and the container runs as uid 10001).
# Usage: deploy/make-dev-secrets.sh [--force] [--dir DIR] [NAME...]
# Kubernetes: kubectl -n surfacer create secret tls surfacer-tls --cert=DIR/tls.crt --key=DIR/tls.key
#             kubectl -n surfacer create secret generic surfacer-tokens --from-file=tokens=DIR/tokens
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"

dir=secrets
force=0
names=(localhost surfacer-1 surfacer-2 surfacer-3 surfacer-headless.surfacer.svc.cluster.local
  surfacer.surfacer.svc.cluster.local)
while [ $# -gt 0 ]; do
  case $1 in
    --force) force=1 ;;
    --dir)
      [ $# -ge 2 ] || { echo "make-dev-secrets: --dir needs a directory" >&2; exit 2; }
      dir=$2
      shift
      ;;
    -h | --help)
      sed -n '2,15p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
      exit 0
      ;;
    -*) echo "make-dev-secrets: unknown option $1 (see --help)" >&2; exit 2 ;;
    *) names+=("$1") ;;
  esac
  shift
done
command -v openssl >/dev/null || { echo "make-dev-secrets: openssl not found (apt-get install openssl)" >&2; exit 2; }

mkdir -p "$dir"
if [ "$force" -eq 0 ] && [ -e "$dir/tls.crt" ]; then
  echo "make-dev-secrets: $dir/tls.crt exists; keeping it (--force makes new ones)" >&2
  exit 0
fi

san="IP:127.0.0.1"
for n in "${names[@]}"; do san+=",DNS:$n"; done
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 10 -subj "/CN=surfacer dev CA" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
  -keyout "$work/ca.key" -out "$work/ca.crt" 2>/dev/null
openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -subj "/CN=surfacer" \
  -keyout "$work/tls.key" -out "$work/tls.csr" 2>/dev/null
printf 'subjectAltName=%s\nextendedKeyUsage=serverAuth\nkeyUsage=critical,digitalSignature\n' "$san" >"$work/ext"
openssl x509 -req -in "$work/tls.csr" -CA "$work/ca.crt" -CAkey "$work/ca.key" -CAcreateserial -days 10 \
  -extfile "$work/ext" -out "$work/tls.crt" 2>/dev/null
openssl verify -CAfile "$work/ca.crt" "$work/tls.crt" >/dev/null

token=$(openssl rand -hex 32)
printf '# TOKEN TENANT [running=N] [bytes=N] (made by deploy/make-dev-secrets.sh)\n%s dev running=8\n' "$token" \
  >"$work/tokens"
printf '%s\n' "$token" >"$work/client-token"

chmod 0600 "$work/ca.key" # never mounted
chmod 0644 "$work/ca.crt" "$work/tls.crt" "$work/tls.key" "$work/tokens" "$work/client-token"
for f in ca.crt ca.key tls.crt tls.key tokens client-token; do mv -f "$work/$f" "$dir/$f"; done
echo "make-dev-secrets: wrote $dir/{ca.crt,ca.key,tls.crt,tls.key,tokens,client-token} for ${names[*]} 127.0.0.1"
