# One image for the gateway and the worker daemons (docker-compose.yml picks the command).
FROM python:3.11-slim
RUN apt-get update && apt-get install -y --no-install-recommends nodejs npm make \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /app
COPY pyproject.toml README.md ./
COPY drlaas drlaas
COPY workers workers
COPY backend backend
COPY frontend frontend
COPY contracts contracts
# CPU torch pinned as in pyproject.toml; a GPU worker image swaps this line for a CUDA build.
RUN pip install --no-cache-dir torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu \
    && pip install --no-cache-dir -e .
ENV DRLAAS_DATA_DIR=/data
# the env's compiled loops (workers/mdrl/kernels.py) are compiled once and kept on the volume
ENV NUMBA_CACHE_DIR=/data/numba-cache
VOLUME /data
EXPOSE 8000
CMD ["uvicorn", "--factory", "backend.api.main:create_app", "--host", "0.0.0.0", "--port", "8000", "--http", "backend.api.http_limits:BoundedHttpToolsProtocol"]
