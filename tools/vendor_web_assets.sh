#!/usr/bin/env bash
# Re-vendor the browser libraries the service serves from service/static/vendor/ (nothing is
# fetched at run time): `npm pack` the pinned versions from the npm registry, check their
# integrity, copy only the files the pages load plus the licences. Bump a version here, run
# this, commit the result (and update service/static/vendor/README.md).
set -euo pipefail
cd "$(dirname "$0")/.."
THREE=0.187.0
THREE_SHA512=Qiu7R+Cmh8CstZsY1uJOSWnVlfo7ZtNLV7mF8Jltk3LB3AtDu9cRZlcnRKkAk8Y4z6KKw35z7Y7Urd7jWY8etA==
SWAGGER=5.35.0
SWAGGER_SHA512=U06rpMtW9V3XPGOBeamTUSr0Z09jMX4IJuANpE/EZbAhw0G8CgwrzU4YmXkn/h0wCDNsXdGarTNNHC3sU8yVUQ==
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
unpack() {  # name version sha512
    (cd "$work" && npm pack --silent "$1@$2" >/dev/null)
    local tgz="$work/$1-$2.tgz"
    local got
    got=$(openssl dgst -sha512 -binary "$tgz" | base64 -w0)
    [ "$got" = "$3" ] || { echo "integrity mismatch for $1@$2: $got" >&2; exit 1; }
    mkdir -p "$work/$1" && tar xzf "$tgz" -C "$work/$1"
}
unpack three "$THREE" "$THREE_SHA512"
unpack swagger-ui-dist "$SWAGGER" "$SWAGGER_SHA512"
dest=service/static/vendor
rm -rf "$dest/three" "$dest/swagger-ui"
src="$work/three/package"
for f in LICENSE build/three.module.js build/three.core.js examples/jsm/controls/OrbitControls.js \
         examples/jsm/loaders/GLTFLoader.js examples/jsm/utils/BufferGeometryUtils.js \
         examples/jsm/utils/SkeletonUtils.js; do
    install -D -m 644 "$src/$f" "$dest/three/$f"
done
src="$work/swagger-ui-dist/package"
for f in LICENSE NOTICE swagger-ui-bundle.js swagger-ui-bundle.js.LICENSE.txt swagger-ui.css favicon-32x32.png; do
    install -D -m 644 "$src/$f" "$dest/swagger-ui/$f"
done
echo "vendored three@$THREE and swagger-ui-dist@$SWAGGER into $dest"
