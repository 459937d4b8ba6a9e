"""A TensorFlow Lite model read from its file and run in NumPy, many inputs at once.

MediaPipe's blendshape head (``face_blendshapes.tflite`` in the Face Landmarker bundle) is a small
MLP-mixer on 146 landmarks: 1x1 convolutions, layer norms, reductions and reshapes. OpenCV's DNN module
refuses it, and the TensorFlow Lite runtime (``ai-edge-litert``) has no wheel for every Blender
(no Intel Mac; 13-22 MB a platform with its dependencies), so facecap runs it here: the file's
flatbuffer is read as the TensorFlow Lite schema lays it out (``schema.fbs``: Model -> SubGraph ->
Tensor / Operator, Buffer), float16 weights are widened once, and the operators run in order on a batch
of inputs (the model's batch of 1 becomes the frames of a take: one call for a whole clip).

Only the operators such heads use are known (``OPS``); any other is refused by name when the model is
loaded, so a model this cannot run fails at once rather than giving wrong numbers. Agreement with the
TensorFlow Lite runtime: ``tests/core/test_face_landmarker.py``.
"""

import struct

import numpy as np

from ..errors import FacecapError

# schema.fbs: BuiltinOperator codes of the operators run here
OPS = {0: "ADD", 2: "CONCATENATION", 3: "CONV_2D", 6: "DEQUANTIZE", 14: "LOGISTIC", 18: "MUL", 22: "RESHAPE",
       39: "TRANSPOSE", 40: "MEAN", 41: "SUB", 42: "DIV", 45: "STRIDED_SLICE", 59: "NEG", 74: "SUM", 75: "SQRT",
       76: "RSQRT", 99: "SQUARED_DIFFERENCE"}
# schema.fbs: TensorType -> NumPy
DTYPES = {0: np.float32, 1: np.float16, 2: np.int32, 3: np.uint8, 4: np.int64, 6: np.bool_, 7: np.int16,
          9: np.int8, 10: np.float64}
CHUNK = 32  # inputs per pass (the blendshape head: 2.4-3.5 ms a frame 8-64 at a time, 5.3 one by one)
ACTIVATIONS = {0: None, 1: lambda x: np.maximum(x, 0.0), 3: lambda x: np.clip(x, 0.0, 6.0), 4: np.tanh}


class _Table:
    """A flatbuffer table at byte ``pos`` of ``buf`` (fields by their index in the schema)."""

    def __init__(self, buf, pos):
        self.buf, self.pos = buf, pos
        vtable = pos - struct.unpack_from("<i", buf, pos)[0]
        size = struct.unpack_from("<H", buf, vtable)[0]
        self.offsets = struct.unpack_from(f"<{(size - 4) // 2}H", buf, vtable + 4)

    def _at(self, field):
        off = self.offsets[field] if field < len(self.offsets) else 0
        return self.pos + off if off else None

    def scalar(self, field, fmt, default=0):
        at = self._at(field)
        return default if at is None else struct.unpack_from("<" + fmt, self.buf, at)[0]

    def _target(self, field):
        at = self._at(field)
        return None if at is None else at + struct.unpack_from("<I", self.buf, at)[0]

    def table(self, field):
        at = self._target(field)
        return None if at is None else _Table(self.buf, at)

    def vector(self, field, dtype):
        """A vector of scalars as a NumPy array (empty when absent)."""
        at = self._target(field)
        if at is None:
            return np.zeros(0, dtype)
        n = struct.unpack_from("<I", self.buf, at)[0]
        return np.frombuffer(self.buf, dtype=np.dtype(dtype).newbyteorder("<"), count=n, offset=at + 4)

    def tables(self, field):
        at = self._target(field)
        if at is None:
            return []
        n = struct.unpack_from("<I", self.buf, at)[0]
        return [_Table(self.buf, at + 4 + 4 * i + struct.unpack_from("<I", self.buf, at + 4 + 4 * i)[0])
                for i in range(n)]

    def string(self, field):
        at = self._target(field)
        if at is None:
            return ""
        n = struct.unpack_from("<I", self.buf, at)[0]
        return bytes(self.buf[at + 4: at + 4 + n]).decode("utf-8", "replace")


class TFLiteGraph:
    """The first subgraph of a TensorFlow Lite model, run in NumPy: ``graph(x) -> [outputs]``.

    Parameters
    ----------
    data : bytes of the ``.tflite`` file
    name : how errors name the model (its file)

    The model's input has a batch of 1 (its first axis); ``__call__`` takes any number N of inputs on that
    axis and returns each output with N on its first axis.
    """

    def __init__(self, data, *, name="model"):
        self.name = name
        buf = memoryview(bytes(data))
        if len(buf) < 8 or bytes(buf[4:8]) != b"TFL3":
            raise FacecapError(f"{name}: not a TensorFlow Lite model (no TFL3 identifier)")
        try:
            self._read(buf)
        except (struct.error, IndexError, ValueError) as exc:
            raise FacecapError(f"{name}: damaged TensorFlow Lite model ({exc})") from None

    def _read(self, buf):
        model = _Table(buf, struct.unpack_from("<I", buf, 0)[0])
        codes = []
        for oc in model.tables(1):
            code = max(oc.scalar(3, "i"), oc.scalar(0, "b"))  # deprecated_builtin_code for old files
            codes.append(code)
        buffers = [b.vector(0, np.uint8) for b in model.tables(4)]
        graph = model.tables(2)[0]
        self.tensors = []
        for t in graph.tables(0):
            kind = t.scalar(1, "b")
            if kind not in DTYPES:
                raise FacecapError(f"{self.name}: tensor '{t.string(3)}' has an unsupported type {kind}")
            data = buffers[t.scalar(2, "I")] if t.scalar(2, "I") < len(buffers) else np.zeros(0, np.uint8)
            shape = tuple(int(s) for s in t.vector(0, np.int32))
            const = data.view(DTYPES[kind]).reshape(shape).copy() if data.size else None
            self.tensors.append({"name": t.string(3), "shape": shape, "value": const})
        self.inputs = [int(i) for i in graph.vector(1, np.int32)]
        self.outputs = [int(i) for i in graph.vector(2, np.int32)]
        self.ops = []
        for op in graph.tables(3):
            code = codes[op.scalar(0, "I")]
            if code not in OPS:
                raise FacecapError(f"{self.name}: operator {code} (TensorFlow Lite's BuiltinOperator) is not one "
                                   f"facecap runs ({', '.join(sorted(OPS.values()))})")
            options = op.table(4)
            self.ops.append((OPS[code], [int(i) for i in op.vector(1, np.int32)],
                             [int(i) for i in op.vector(2, np.int32)], options))
        folded = []
        for op in self.ops:  # float16 weights widened once, not on every call
            kind, ins, outs, _options = op
            if kind == "DEQUANTIZE" and self.tensors[ins[0]]["value"] is not None:
                self.tensors[outs[0]]["value"] = self.tensors[ins[0]]["value"].astype(np.float32)
            else:
                folded.append(op)
        self.ops = folded
        for kind, ins, _outs, options in self.ops:
            if kind == "CONV_2D":
                shape = self.tensors[ins[1]]["shape"]
                strides = (options.scalar(1, "i", 1), options.scalar(2, "i", 1)) if options else (1, 1)
                if shape[1:3] != (1, 1) or strides != (1, 1):
                    raise FacecapError(f"{self.name}: only 1x1 convolutions with stride 1 are run; got a "
                                       f"{shape[1]}x{shape[2]} kernel, strides {strides}")

    @property
    def input_shape(self):
        return self.tensors[self.inputs[0]]["shape"]

    def __call__(self, x, *, chunk=CHUNK):
        x = np.asarray(x, dtype=np.float32)
        want = self.input_shape
        if x.ndim != len(want) or x.shape[1:] != tuple(want[1:]):
            raise FacecapError(f"{self.name}: input must have shape (N, {', '.join(map(str, want[1:]))}); "
                               f"got {x.shape}")
        if len(x) > chunk:  # a few frames at a time: the layers' tensors stay in the processor's cache
            parts = [self(x[i: i + chunk]) for i in range(0, len(x), chunk)]
            return [np.concatenate(p) for p in zip(*parts)]
        values = {self.inputs[0]: x}

        def get(i):
            if i in values:
                return values[i]
            const = self.tensors[i]["value"]
            if const is None:
                raise FacecapError(f"{self.name}: tensor '{self.tensors[i]['name']}' is read before it is written")
            return const

        for kind, ins, outs, options in self.ops:
            values[outs[0]] = self._run(kind, [get(i) if i >= 0 else None for i in ins], options, len(x))
        return [values[i] for i in self.outputs]

    @staticmethod
    def _run(kind, a, options, n):
        """One operator on a batch of ``n``: the batch is axis 0 of every computed tensor."""
        act = ACTIVATIONS.get(options.scalar(0, "b") if options is not None and kind in
                              ("ADD", "SUB", "MUL", "DIV") else 0)
        if kind == "DEQUANTIZE":
            return a[0].astype(np.float32)
        if kind in ("ADD", "SUB", "MUL", "DIV", "SQUARED_DIFFERENCE"):
            x, y = a
            out = {"ADD": np.add, "SUB": np.subtract, "MUL": np.multiply, "DIV": np.divide,
                   "SQUARED_DIFFERENCE": lambda p, q: (p - q) ** 2}[kind](x, y)
            return out if act is None else act(out)
        if kind in ("MEAN", "SUM"):
            axes = tuple(int(v) for v in np.atleast_1d(a[1]))
            keep = bool(options.scalar(0, "b")) if options is not None else False
            return (np.mean if kind == "MEAN" else np.sum)(a[0], axis=axes, keepdims=keep)
        if kind == "NEG":
            return -a[0]
        if kind == "SQRT":
            return np.sqrt(a[0])
        if kind == "RSQRT":
            return 1.0 / np.sqrt(a[0])
        if kind == "LOGISTIC":
            return 1.0 / (1.0 + np.exp(-a[0]))
        if kind == "RESHAPE":
            shape = [int(v) for v in a[1]] if len(a) > 1 and a[1] is not None else \
                [int(v) for v in options.vector(0, np.int32)]
            return a[0].reshape([n] + shape[1:])  # the model's batch of 1 is the batch
        if kind == "TRANSPOSE":
            perm = [int(v) for v in a[1]]
            if perm[0] != 0:
                raise FacecapError(f"TRANSPOSE: a permutation that moves the batch axis ({perm}) is not run")
            return np.transpose(a[0], perm)
        if kind == "CONCATENATION":
            axis = options.scalar(0, "i")
            parts = [np.broadcast_to(p, (n,) + p.shape[1:]) if p.shape[0] == 1 else p for p in a]
            return np.concatenate(parts, axis=axis)
        if kind == "CONV_2D":  # 1x1, stride 1 (checked on loading): a matrix product on the channels
            x, w = a[0], a[1]
            out = (x.reshape(-1, x.shape[-1]) @ w.reshape(w.shape[0], -1).T).reshape(x.shape[:-1] + (w.shape[0],))
            if len(a) > 2 and a[2] is not None:
                out = out + a[2]
            act = ACTIVATIONS.get(options.scalar(3, "b") if options is not None else 0)
            return out if act is None else act(out)
        if kind == "STRIDED_SLICE":
            return _strided_slice(a[0], a[1], a[2], a[3], options)
        raise FacecapError(f"operator {kind} is not run")  # unreachable: refused when loading


def _strided_slice(x, begin, end, strides, options):
    """TensorFlow Lite's STRIDED_SLICE with begin/end/shrink masks; axis 0 (the batch) is kept whole."""
    begin_mask, end_mask = (options.scalar(0, "i"), options.scalar(1, "i")) if options else (0, 0)
    shrink = options.scalar(4, "i") if options else 0
    if options is not None and (options.scalar(2, "i") or options.scalar(3, "i")):
        raise FacecapError("STRIDED_SLICE with ellipsis or new-axis masks is not run")
    index, squeeze = [slice(None)], []
    for d in range(1, x.ndim):
        b = None if begin_mask >> d & 1 else int(begin[d])
        e = None if end_mask >> d & 1 else int(end[d])
        if shrink >> d & 1:
            index.append(slice(b, (b + 1) or None))
            squeeze.append(d)
        else:
            index.append(slice(b, e, int(strides[d])))
    out = x[tuple(index)]
    return out.reshape([s for d, s in enumerate(out.shape) if d not in squeeze]) if squeeze else out
