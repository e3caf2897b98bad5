#!/usr/bin/env bash
# The containers, built and run for real with Debian's podman and runc (what .ci/run does after the
# test suite; docs/service.md, "Containers"):
#   1. a base image made from Debian's packages (mmdebstrap --variant=minbase: python3, its venv
#      module, CA certificates, curl), imported into podman (once per machine);
#   2. the server and the client images on it (docker/server.Dockerfile, docker/client.Dockerfile,
#      BASE_IMAGE set to that base), pip inside the build using this machine's pip settings;
#   3. the server container on 127.0.0.1:$PORT with an API key, until it is ready (/readyz);
#   4. the client container's end-to-end suite against it (the key in CAPSULE_RT_KEY).
# Exits non-zero on any failure. Needs root and the Debian packages podman, runc and mmdebstrap.
#
# Why these settings (checked on this project's machines: root in a container, no systemd):
#   containers.conf  default_ulimits = []: podman's default open-files limit cannot be set here
#                    (runc: "error setting rlimit type 7: operation not permitted"); cgroup_manager =
#                    "cgroupfs": there is no systemd to ask for cgroups;
#   --runtime runc   Debian's runc (crun is not installed);
#   --network host   builds and containers use the host's network: pip and apt reach the package
#                    indexes as the host does, and the client reaches the server on 127.0.0.1 (where
#                    the server listens, so nothing beyond this machine can reach it);
#   pip settings     the machine reaches the package index through its own pip configuration and
#                    certificate (PIP_CERT): those files are mounted read-only into every build step;
#   --format docker  the OCI format has no HEALTHCHECK, and the server image declares one.
set -euo pipefail
cd "$(dirname "$0")/.."

PORT=${CAPSULE_RT_CI_PORT:-18000}
BASE=${CAPSULE_RT_BASE_IMAGE:-localhost/capsule-rt-base:bookworm}
work=$(mktemp -d)
server=""
cleanup() {
  [ -n "$server" ] && podman rm -f "$server" >/dev/null 2>&1 || true
  rm -rf "$work"
}
trap cleanup EXIT

export CONTAINERS_CONF="$work/containers.conf"
cat > "$CONTAINERS_CONF" <<'EOF'
[containers]
default_ulimits = []
[engine]
cgroup_manager = "cgroupfs"
EOF
podman=(podman --runtime runc)
secs() { echo $(( $(date +%s) - $1 )); }

# 1. the base image, made once per machine (CAPSULE_RT_CI_FRESH_BASE=1: again). Kept, it keeps the
# images' dependency layers cached between runs while pyproject.toml does not change.
t=$(date +%s)
if [ "${CAPSULE_RT_CI_FRESH_BASE:-0}" = 1 ] || ! "${podman[@]}" image exists "$BASE"; then
  mmdebstrap --quiet --variant=minbase --include=python3,python3-venv,ca-certificates,curl bookworm "$work/base.tar"
  "${podman[@]}" import --quiet "$work/base.tar" "$BASE" >/dev/null
  rm -f "$work/base.tar"
  echo "podman-ci: base image $BASE made from Debian's packages in $(secs "$t") s"
else
  echo "podman-ci: base image $BASE as made on $("${podman[@]}" image inspect --format '{{.Created}}' "$BASE")"
fi

# 2. the images; pip inside the build reads this machine's pip configuration and certificate
mounts=()
for f in /etc/pip.conf /etc/xdg/pip "$HOME/.config/pip" "$HOME/.pip" "${PIP_CONFIG_FILE:-}" "${PIP_CERT:-}"; do
  [ -n "$f" ] && [ -e "$f" ] && mounts+=(-v "$f:$f:ro")
done
envs=()
[ -n "${PIP_CERT:-}" ] && envs+=(--env "PIP_CERT=$PIP_CERT")
for image in server client; do
  t=$(date +%s)
  "${podman[@]}" build --quiet --format docker --network host --pull=never --build-arg "BASE_IMAGE=$BASE" "${mounts[@]}" \
    "${envs[@]}" -f "docker/$image.Dockerfile" -t "localhost/capsule-rt-$image:ci" . >/dev/null
  echo "podman-ci: $image image built in $(secs "$t") s"
done
label=$("${podman[@]}" image inspect --format '{{ index .Labels "io.capsule-rt.fullwave" }}' localhost/capsule-rt-server:ci)
echo "podman-ci: the server image carries gprMax: $([ "$label" = 1 ] && echo yes || echo "no (POST /v1/fullwave answers 501)")"

# 3. the server, bound to the loopback (host network) and requiring an API key for writes
key=$(head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n')
t=$(date +%s)
server=$("${podman[@]}" run -d --network host \
  -e CAPSULE_RT_HOST=127.0.0.1 -e "CAPSULE_RT_PORT=$PORT" -e "CAPSULE_RT_API_KEYS=$key" \
  -e CAPSULE_RT_MAX_CONCURRENCY=2 -e CAPSULE_RT_MAX_QUEUE=2 -e CAPSULE_RT_LOG_LEVEL=warning \
  localhost/capsule-rt-server:ci)
ready=""
for _ in $(seq 1 300); do
  if curl -fsS "http://127.0.0.1:$PORT/readyz" >/dev/null 2>&1; then ready=1; break; fi
  [ "$("${podman[@]}" inspect --format '{{.State.Running}}' "$server")" = true ] || break
  sleep 1
done
if [ -z "$ready" ]; then
  echo "podman-ci: the server container never became ready; its log:" >&2
  "${podman[@]}" logs "$server" 2>&1 | tail -50 >&2
  exit 1
fi
echo "podman-ci: server container ready in $(secs "$t") s"
# the key is required: an upload without it is refused
status=$(curl -s -o /dev/null -w '%{http_code}' -X DELETE "http://127.0.0.1:$PORT/v1/phantoms/up-0123456789abcdef")
[ "$status" = 401 ] || { echo "podman-ci: a delete without the key got $status, not 401" >&2; exit 1; }

# 4. the client's end-to-end suite against it. Left out, and run by the main suite instead: the
# browser tests (no Chromium in the client image) and the three modules that start servers of
# their own inside the client (the live fuzzing, the sweep and full-wave job flows).
t=$(date +%s)
"${podman[@]}" run --rm --network host -e "CAPSULE_RT_URL=http://127.0.0.1:$PORT" -e "CAPSULE_RT_KEY=$key" \
  localhost/capsule-rt-client:ci -q -m "e2e and not browser" \
  --ignore=tests/e2e/test_live_fuzz.py --ignore=tests/e2e/test_sweeps_http.py \
  --ignore=tests/e2e/test_fullwave_http.py
echo "podman-ci: client suite against the server container in $(secs "$t") s"
