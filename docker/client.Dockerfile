# CapsuleRT end-to-end test client: runs the e2e suite against CAPSULE_RT_URL.
# `docker build -f docker/client.Dockerfile -t capsule-rt-client .` (context: repo root).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    CAPSULE_RT_URL=http://server:8000

# curl: the README's curl examples (docs/curl_examples.sh) are part of the suite.
# hadolint ignore=DL3008
RUN apt-get update \
    && apt-get install -y --no-install-recommends curl \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app
COPY pyproject.toml README.md ./
COPY raytrace ./raytrace
COPY estimators ./estimators
COPY service ./service
COPY plots ./plots
COPY evaluation ./evaluation
COPY sweeps ./sweeps
COPY vision ./vision
COPY fullwave ./fullwave
COPY tracking ./tracking
# The local project with its test extra; versions are constrained in pyproject.toml.
# hadolint ignore=DL3013
RUN pip install --no-cache-dir ".[test]" \
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
