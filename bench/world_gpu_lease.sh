#!/bin/bash
# World-model variants trained on a lent GPU from a packed bundle (bench/world_gpu.py), in one call.
#
# Here, first (docs/benchmarks.md#benchworld_gpupy):
#   .venv/bin/python bench/world_gpu.py pack manifests/push_closeup.yaml --also manifests/push_closeup_noisy.yaml \
#       --tokenizer ID --action-totals 3 --out bench/out/gpu/bundle.pt
#   the wheels the lent machine lacks, into bench/out/gpu/whl (pydantic, pydantic_core, annotated_types,
#   typing_inspection, typing_extensions, simplemma; cp312, manylinux: docs/benchmarks.md gives the command).
# Then on the device, carrying bench/out/gpu/whl and bench/out/gpu/bundle.pt:
#   SECONDS_CAP=330 bash bench/world_gpu_lease.sh 'name=long8' 'name=win8 batch=16 window=8' ...
# Every variant post-trains for SECONDS_CAP seconds unless its own post_steps or seconds says otherwise (keys:
# bench/world_gpu.py DEFAULTS). Each post-trained checkpoint comes back as $OUT/NAME.tar, split into 15 MiB parts
# (NAME.tar.aa, ...) when larger; `cat NAME.tar* | tar xf -` here gives NAME/posttrain, which `worldline evaluate
# policies --world-model NAME/posttrain` reads beside the data root the bundle was packed from.
set -u
[ $# -ge 1 ] || { echo "usage: world_gpu_lease.sh 'name=N key=value ...' ..." >&2; exit 2; }
OUT=${OUT:-/tmp/world_gpu_out}
WORK=${WORK:-/tmp/wg}  # where the variants are trained
mkdir -p "$OUT" "$WORK"
PY=${PYTHON:-python3}  # PYTHON=.venv/bin/python DEVICE=cpu tries it here, without the wheels
DEVICE=${DEVICE:-cuda}
if [ -d bench/out/gpu/whl ] && [ -z "${PYTHON:-}" ]; then
    $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
        bench/out/gpu/whl/*.whl && export PYTHONPATH=/tmp/site || exit 3
fi
export PYTHONUNBUFFERED=1
# PyAV (35 MB) does not fit beside the bundle in the 64 MiB a call carries; training from a bundle never decodes
# video, so where it is missing a module that fails on first use stands in for the import.
if ! $PY -c 'import av' 2>/dev/null; then
    mkdir -p /tmp/site/av
    printf 'def __getattr__(name):\n    raise ImportError("PyAV is not installed here")\n' > /tmp/site/av/__init__.py
    case ":${PYTHONPATH:-}:" in *:/tmp/site:*) ;; *) export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH} ;; esac
fi
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
$PY -c "import torch, tasks.manifests, tasks.world.phases
print('torch', torch.__version__, torch.cuda.is_available() and torch.cuda.get_device_name())" || exit 4
variants=()
for spec in "$@"; do variants+=(--variant "post_steps=1000000 seconds=${SECONDS_CAP:-330} $spec"); done
date -u +%T
compile=--compile; [ "$DEVICE" = cpu ] && compile=
$PY bench/world_gpu.py train "${BUNDLE:-bench/out/gpu/bundle.pt}" --out "$WORK" --device "$DEVICE" $compile \
    --threads 2 "${variants[@]}" 2>&1 | grep -v -i warn | tee "$OUT/log.txt"
trained=${PIPESTATUS[0]}
date -u +%T
cd "$WORK" || exit 5
for spec in "$@"; do  # every variant that finished, also when another failed
    name=$(echo "$spec" | tr ' ' '\n' | sed -n 's/^name=//p')
    [ -f "$name/result.json" ] || { echo "$name: not finished, nothing to return" >&2; continue; }
    tar cf - "$name/posttrain/config.json" "$name/posttrain/model.safetensors" "$name/result.json" > "$OUT/$name.tar"
    if [ "$(stat -c %s "$OUT/$name.tar")" -gt 15728640 ]; then
        split -b 15m "$OUT/$name.tar" "$OUT/$name.tar." && rm "$OUT/$name.tar"
    fi
done
ls -la "$OUT"
exit "$trained"
