# CapsuleRT API server: `docker build -f docker/server.Dockerfile -t capsule-rt .` (context: repo root).
# Build arguments (docs/service.md, "Containers"):
#   BASE_IMAGE  any Debian-based image with python3 (>= 3.11) and its venv module; default the slim
#               Python image. CI builds on one made from Debian's packages (docker/base.sh).
#   FULLWAVE    1: install gprMax (the `fullwave` extra), so POST /v1/fullwave runs its jobs; 0 (the
#               default): the image has no gprMax and POST /v1/fullwave answers 501 for every job
#               but an export-only one. The image's label io.capsule-rt.fullwave says which.
ARG BASE_IMAGE=python:3.11-slim

# scikit-fmm (estimators' eikonal solver) is published on PyPI as source only: its wheel is
# compiled in this stage, and only the wheel reaches the image (no compiler there).
# hadolint ignore=DL3006
FROM ${BASE_IMAGE} AS scikit-fmm
WORKDIR /src
COPY pyproject.toml ./
# hadolint ignore=DL3008,DL3013,SC2046
RUN headers=$(python3 -c "import os, sysconfig; print(os.path.exists(sysconfig.get_path('include') + '/Python.h'))") \
    && apt-get update \
    && apt-get install -y --no-install-recommends g++ $([ "$headers" = True ] || echo python3-dev) \
    && rm -rf /var/lib/apt/lists/* \
    && python3 -m venv /opt/build \
    && requirement=$(python3 -c "import tomllib; print(*[d.split(' ')[0] for d in tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies'] if d.startswith('scikit-fmm')])") \
    && /opt/build/bin/pip wheel --no-cache-dir --no-deps --wheel-dir /wheels "$requirement"

# hadolint ignore=DL3006
FROM ${BASE_IMAGE}
ARG FULLWAVE=0

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PATH=/opt/capsule-rt/bin:$PATH \
    CAPSULE_RT_HOST=0.0.0.0 \
    CAPSULE_RT_PORT=8000 \
    CAPSULE_RT_DATA_DIR=/data \
    NUMBA_CACHE_DIR=/var/cache/capsule-rt/numba \
    CAPSULE_RT_CACHE_DIR=/var/cache/capsule-rt
LABEL io.capsule-rt.fullwave="${FULLWAVE}"

WORKDIR /app
COPY --from=scikit-fmm /wheels /wheels

# Install from pyproject.toml into a virtual environment: first its dependencies (plus gprMax when
# FULLWAVE=1; embreex ships manylinux wheels), a layer that a rebuild reuses while pyproject.toml
# is unchanged, then the project itself.
COPY pyproject.toml README.md ./
# hadolint ignore=DL3013,SC2046
RUN python3 -m venv /opt/capsule-rt \
    && python3 -c "import sys, tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; print(*p['dependencies'], *[d for e in sys.argv[1:] for d in p['optional-dependencies'][e]], sep='\\n')" \
       $([ "$FULLWAVE" = 1 ] && echo fullwave) > /tmp/requirements.txt \
    && pip install --no-cache-dir --find-links /wheels -r /tmp/requirements.txt \
    && rm /tmp/requirements.txt
COPY raytrace ./raytrace
COPY estimators ./estimators
COPY service ./service
COPY plots ./plots
COPY evaluation ./evaluation
COPY sweeps ./sweeps
COPY vision ./vision
COPY fullwave ./fullwave
COPY tracking ./tracking
COPY design ./design
# The warm-up compiles the tracer's numba kernels into the image, so a container's start does
# not pay the ~17 s compile. It imports the installed package (-P: not /app, the working directory), the
# one `capsule-rt serve` imports (numba's cache is keyed on the source file). numba only uses a
# cache directory it can write to: the cache is handed to the service's user. The built-in CT abdomen is
# built into the image the same way (raytrace/body/abdomen.py: ~1 min of CPU once, then loaded in ~0.2 s).
# hadolint ignore=DL3013
RUN pip install --no-cache-dir --no-deps . \
    && python -P -c "from raytrace.solver.tracer import warm_up; warm_up()" \
    && python -P -m raytrace.body.abdomen \
    && groupadd --system --gid 10001 capsule \
    && useradd --system --create-home --uid 10001 --gid 10001 capsule \
    && mkdir -p /data \
    && chown capsule:capsule /data \
    && chown -R capsule:capsule "$NUMBA_CACHE_DIR" "$CAPSULE_RT_CACHE_DIR"

USER 10001:10001
EXPOSE 8000
VOLUME ["/data"]

# Healthy = ready: built-in phantoms loaded and the Embree engine available.
HEALTHCHECK --interval=10s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/readyz', timeout=4).status == 200 else 1)"]

CMD ["capsule-rt", "serve"]
