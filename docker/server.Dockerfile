# CapsuleRT API server: `docker build -f docker/server.Dockerfile -t capsule-rt .` (context: repo root).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    CAPSULE_RT_HOST=0.0.0.0 \
    CAPSULE_RT_PORT=8000 \
    CAPSULE_RT_DATA_DIR=/data \
    NUMBA_CACHE_DIR=/var/cache/capsule-rt/numba

WORKDIR /app

# Install from pyproject.toml (core dependencies only; embreex ships manylinux wheels).
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
# The warm-up compiles the tracer's numba kernels into the image, so a container's start does
# not pay the ~17 s compile. numba only uses a cache directory it can write to: the cache is
# handed to the service's user.
RUN pip install --no-cache-dir . \
    && python -c "from raytrace.solver.tracer import warm_up; warm_up()" \
    && groupadd --system --gid 10001 capsule \
    && useradd --system --create-home --uid 10001 --gid 10001 capsule \
    && mkdir -p /data \
    && chown capsule:capsule /data \
    && chown -R capsule:capsule "$NUMBA_CACHE_DIR"

USER 10001:10001
EXPOSE 8000
VOLUME ["/data"]

# Healthy = ready: built-in phantoms loaded and the Embree engine available.
HEALTHCHECK --interval=10s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/readyz', timeout=4).status == 200 else 1)"]

CMD ["capsule-rt", "serve"]
