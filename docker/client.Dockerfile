# CapsuleRT end-to-end test client: runs the e2e suite against CAPSULE_RT_URL (sending CAPSULE_RT_KEY,
# when set, as the API key of the writes).
# `docker build -f docker/client.Dockerfile -t capsule-rt-client .` (context: repo root).
# BASE_IMAGE: as in server.Dockerfile (default the slim Python image; CI: docker/base.sh).
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

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PATH=/opt/capsule-rt/bin:$PATH \
    CAPSULE_RT_URL=http://server:8000

# curl: the README's curl examples (docs/curl_examples.sh) are part of the suite (installed from
# Debian's packages when the base image lacks it).
# hadolint ignore=DL3008
RUN command -v curl >/dev/null || { apt-get update \
    && apt-get install -y --no-install-recommends curl \
    && rm -rf /var/lib/apt/lists/*; }

WORKDIR /app
COPY --from=scikit-fmm /wheels /wheels
# Its dependencies first (a layer a rebuild reuses while pyproject.toml is unchanged), then the project.
COPY pyproject.toml README.md ./
# hadolint ignore=DL3013
RUN python3 -m venv /opt/capsule-rt \
    && python3 -c "import sys, tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; print(*p['dependencies'], *[d for e in sys.argv[1:] for d in p['optional-dependencies'][e]], sep='\\n')" test > /tmp/requirements.txt \
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
# The local project with its test extra, in a virtual environment; versions are constrained in
# pyproject.toml.
# hadolint ignore=DL3013
RUN pip install --no-cache-dir --no-deps . \
    && groupadd --system --gid 10001 tester \
    && useradd --system --create-home --uid 10001 --gid 10001 tester
# Only the end-to-end suite (it imports the installed packages, never bench/ or the unit
# tests' helpers): tests/service/test_docker.py builds exactly this file set and runs the
# entry point below against a live server.
COPY tests/__init__.py tests/conftest.py tests/schemathesis_hooks.py ./tests/
COPY tests/e2e ./tests/e2e
COPY docs ./docs

USER 10001:10001
ENTRYPOINT ["python", "-m", "pytest", "-m", "e2e", "-p", "no:cacheprovider", "tests"]
CMD ["-q"]
