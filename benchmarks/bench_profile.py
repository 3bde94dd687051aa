"""Benchmark: where a fit's time goes, stage by stage, and the renderer against a native visibility floor.

    OMP_NUM_THREADS=1 taskset -c 1 .venv/bin/python benchmarks/bench_profile.py \\
        /work/data/study2/sequences/medium-light_flip_front_sun/gt-noise \\
        --presets fast,full --max-frames 30 --steps 3 --out /tmp/bench_profile.json

(the figures in docs/performance.md#where-the-time-goes-and-the-native-floor: about 4.5 minutes,
one torch thread pinned to core 1 while core 0 ran fits). Two parts, measured in one run:

1. The native floor (`--sizes 256 448`, `--frames 8`, the subdivided hand model posed and seen
   exactly as benchmarks/bench_renderer.py does). Milliseconds per frame, median of
   `--repeats` alternating rounds (timing.alternating_medians), of:
   - our rasteriser alone (fused.rasterize: face index and depth per pixel; forward only, no
     gradients exist), all frames in one call;
   - open3d's Embree (`open3d.t.geometry.RaycastingScene`): one primary ray per pixel centre
     (i + 0.5, j + 0.5) through the same K, OpenCV axes (the direction K^-1 (u, v, 1) has z = 1,
     so the hit distance is the depth); the scene is built for every frame (a new pose is a new
     BVH), one thread for building and casting (`nthreads=1`). "cast only" is a second cast on the
     already built scene. Its hit face ids are compared with our face buffer on the pixels
     either covers (Embree sees back faces, which we cull: the hand's open wrist);
   - moderngl on a headless EGL context (Mesa llvmpipe, LP_NUM_THREADS=1), the same triangles
     into a float face-id framebuffer with a depth buffer, back faces culled, per frame:
     vertex upload, clear, draw and readback;
   - our forward+backward of the shaded + shadows render (bench_renderer.run).
   open3d and moderngl are optional: a missing one is reported "not installed" and skipped.

2. A stage-by-stage profile of a fit: for each preset the fit problem is built as `harp fit`
   builds it (fitting._set_up, with max_frames), and, as estimate.calibrate does, each step kind
   (align, geometry, geometry+appearance and appearance, the last two with and without
   self-shadowing) is run on a fresh StageRun: one warm-up step, then `--steps` steps timed
   plainly, `--steps` under torch.profiler and `--steps` plainly again, the three phases on the
   same batches of frames (the "plain" column is the mean of the plain steps); the avatar is
   put back after each kind. The step's pieces are wrapped in torch.profiler.record_function
   ranges by monkeypatching (nothing in pipeline/ changes): avatar posing (skinning +
   displacement), the renderer's primitives (rasterise, fragments, interpolation, normals and
   tangents, texture lookup, shading, shadow map and its own rasterisation, antialias,
   composite, the rest of render()), each loss term (losses.py's functions and the perceptual
   term), the rest of the energy ("losses (other)": the textures' normalisation, the weighted
   sum), the optimiser step (Adam with the lazy per-frame restore) and torch.autograd.backward.

   Attribution: a piece's forward time is the time inside its range less that of ranges nested
   in it. Its backward time is found through the profiler's sequence numbers: every autograd
   node carries the sequence number of the forward operator that made it, and the backward's
   "autograd::engine::evaluate_function: <Node>" event carries the same number (operators that
   make no node, such as an index into a tensor without gradients, record the number the next
   node will take: the last forward operator to record a number is the one that made it); the
   node's whole time (its own and its children's operators) goes to the innermost range that
   held the forward operator. Backward time that maps to no range (AccumulateGrad into the
   parameters, the engine's own work between nodes, the loss's chunk scaling) and everything
   else in the step (batch choice, checks, zero_grad) is "rest", with the optimiser beside it.
   The profiler records every operator, which costs a little: both totals are printed, and
   the split is the profiled steps'. Summary columns: rasterize (the camera's and the shadow
   map's), the renderer after visibility, the losses, skinning + displacement, the optimiser,
   the rest; each with the backward it caused.

Tables go to stdout; --out writes everything as JSON. --skip-floor or --skip-fit runs one part.
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import copy
import dataclasses
import functools
import json
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

RANGE = "harp::"
KINDS = ("align", "geometry", "geometry+appearance", "geometry+appearance shadows", "appearance",
         "appearance shadows")
# each range's column in the summary
COLUMNS = {
    "rasterize": "rasterize", "rasterize (shadow map)": "rasterize",
    "fragments": "after visibility", "interpolation": "after visibility",
    "normals and tangents": "after visibility", "texture lookup": "after visibility",
    "shading": "after visibility", "shadow map": "after visibility", "antialias": "after visibility",
    "composite": "after visibility", "render (other)": "after visibility",
    "losses (other)": "losses", "posing": "posing", "optimiser": "optimiser",
}
LOSS_TERMS = ("silhouette", "keypoint_anchor", "temporal_pose", "temporal_global", "displacement", "laplacian",
              "displacement_smoothness", "normal_consistency", "edge_length", "photometric", "perceptual",
              "texture_smoothness", "normal_map", "exposure")
COLUMNS.update({f"loss: {term}": "losses" for term in LOSS_TERMS})
SHORT = {"align": "align", "geometry": "geometry", "geometry+appearance": "geo+app",
         "geometry+appearance shadows": "geo+app shadow", "appearance": "app", "appearance shadows": "app shadow"}
SUMMARY = ("rasterize", "after visibility", "losses", "posing", "optimiser", "rest")
SUMMARY_TITLES = {"rasterize": "rasterize", "after visibility": "render after vis.", "losses": "losses",
                  "posing": "skin + displ.", "optimiser": "optimiser", "rest": "rest"}
OPTIONAL_MISSING = "not installed"


# ----------------------------------------------------------------------------------------------
# part 1: the native floor


def camera(size, device="cpu"):
    """bench_renderer's K for a square image of `size` pixels."""
    import torch

    return torch.tensor([[size * 2.0, 0, size / 2], [0, size * 2.0, size / 2], [0, 0, 1]], device=device)


def pixel_rays(K, height, width):
    """(H, W, 6) float32 rays from the origin through the pixel centres (i + 0.5, j + 0.5), the
    rasteriser's convention; directions with z = 1, so a hit distance is a depth."""
    import numpy as np

    K = np.asarray(K, dtype=np.float64)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    direction = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    return np.concatenate([np.zeros_like(direction), direction], axis=-1).astype(np.float32)


class EmbreeCaster:
    """open3d's RaycastingScene (Embree), one thread: a scene per frame, one ray per pixel."""

    def __init__(self, faces, K, size):
        import open3d as o3d

        self.o3d = o3d
        self.faces = o3d.core.Tensor(faces.astype("uint32"))
        self.rays = o3d.core.Tensor(pixel_rays(K, size, size))
        self.size = size

    def scene(self, vertices):
        scene = self.o3d.t.geometry.RaycastingScene(nthreads=1)
        scene.add_triangles(self.o3d.core.Tensor(vertices.astype("float32")), self.faces)
        return scene

    def cast(self, scene):
        hits = scene.cast_rays(self.rays, nthreads=1)
        return hits["primitive_ids"].numpy(), hits["t_hit"].numpy()

    def frames(self, vertices):
        """(face ids (B, H, W) with -1 for misses, depth (B, H, W)) of every frame, built and cast."""
        import numpy as np

        faces, depths = [], []
        for frame in vertices:
            ids, depth = self.cast(self.scene(frame))
            faces.append(np.where(ids == self.o3d.t.geometry.RaycastingScene.INVALID_ID, -1, ids.astype(np.int64)))
            depths.append(depth)
        return np.stack(faces), np.stack(depths)


class GLFaceIds:
    """Face ids by OpenGL (moderngl, headless EGL: Mesa's llvmpipe on a CPU), one frame at a time:
    vertex upload, clear, draw with depth test and back faces culled, readback."""

    VERTEX = """
        #version 330
        uniform vec4 intrinsics;     // fx, fy, cx, cy
        uniform vec2 size;           // width, height
        uniform vec2 clip;           // near, far
        in vec3 position;            // camera frame, OpenCV axes
        void main() {
            float z = position.z;
            float n = clip.x, f = clip.y;
            // pixel u = fx x / z + cx -> NDC 2 u / W - 1 (and v likewise, so that row 0 of the
            // readback is the image's top row); the depth is the usual perspective one
            gl_Position = vec4(2.0 * (intrinsics.x * position.x + intrinsics.z * z) / size.x - z,
                               2.0 * (intrinsics.y * position.y + intrinsics.w * z) / size.y - z,
                               ((f + n) * z - 2.0 * f * n) / (f - n), z);
        }"""
    FRAGMENT = """
        #version 330
        out float face;
        void main() { face = float(gl_PrimitiveID + 1); }"""

    def __init__(self, faces, vertex_count, K, size):
        os.environ.setdefault("LP_NUM_THREADS", "1")   # llvmpipe's rasteriser threads: read at context creation
        import moderngl

        self.ctx = moderngl.create_context(standalone=True, backend="egl")
        self.renderer = self.ctx.info.get("GL_RENDERER", "?")
        program = self.ctx.program(vertex_shader=self.VERTEX, fragment_shader=self.FRAGMENT)
        program["intrinsics"].value = (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
        program["size"].value = (float(size), float(size))
        program["clip"].value = (0.01, 10.0)
        self.vertices = self.ctx.buffer(reserve=vertex_count * 12)
        indices = self.ctx.buffer(faces.astype("uint32").tobytes())
        self.vao = self.ctx.vertex_array(program, [(self.vertices, "3f", "position")], index_buffer=indices,
                                         index_element_size=4)
        self.fbo = self.ctx.framebuffer(color_attachments=[self.ctx.texture((size, size), 1, dtype="f4")],
                                        depth_attachment=self.ctx.depth_renderbuffer((size, size)))
        self.ctx.enable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        # the NDC y axis points down the image here, which mirrors the winding: OpenCV's
        # front faces (normal towards the camera) come out clockwise
        self.ctx.front_face = "cw"
        self.size = size

    def frame(self, vertices):
        import numpy as np

        self.vertices.write(vertices.astype("float32").tobytes())
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.vao.render()
        ids = np.frombuffer(self.fbo.read(components=1, dtype="f4"), dtype=np.float32)
        return ids.reshape(self.size, self.size).astype(np.int64) - 1

    def frames(self, vertices):
        import numpy as np

        return np.stack([self.frame(frame) for frame in vertices])


def agreement(ours, theirs):
    """Face-id agreement of two (B, H, W) buffers (-1: empty) over the pixels either covers, and
    over the pixels both cover; the coverage IoU."""
    either = (ours >= 0) | (theirs >= 0)
    both = (ours >= 0) & (theirs >= 0)
    same = (ours == theirs) & both
    return {"agree_on_either": float(same.sum() / max(1, either.sum())),
            "agree_on_both": float(same.sum() / max(1, both.sum())),
            "coverage_iou": float(both.sum() / max(1, either.sum())), "covered_pixels": int(either.sum())}


def native_floor(args):
    """Part 1: {size: {path: ms per frame, ...}} and the agreement figures."""
    import numpy as np
    import torch
    from bench_renderer import WORKLOADS, parameters, run, scene
    from timing import alternating_medians

    from pipeline.render import fused

    model, points, mesh = scene(args.frames, "hand", "cpu")
    params = parameters("cpu")
    faces = mesh.faces.numpy()
    vertices = points.numpy()
    print(f"\n== native floor: hand model subdivided, {model.data.num_vertices} vertices, {len(faces)} faces; "
          f"{args.frames} frames; torch {torch.__version__}, {torch.get_num_threads()} thread(s)")
    results = {"vertices": int(model.data.num_vertices), "faces": int(len(faces)), "frames": args.frames,
               "sizes": {}}
    notes = {}
    for size in args.sizes:
        K = camera(size)
        paths = {"ours: rasterize (fused)": lambda: fused.rasterize(points, mesh.faces, K, size, size),
                 "ours: shaded + shadows, forward+backward": lambda: run(points, mesh, size,
                                                                          WORKLOADS["shaded + shadows"], params)}
        ours = fused.rasterize(points, mesh.faces, K, size, size)
        our_faces = ours.face.numpy()
        checks = {}
        embree = _optional("open3d", lambda: EmbreeCaster(faces, K.numpy(), size), notes)
        if embree is not None:
            built = [embree.scene(frame) for frame in vertices]
            for scene_ in built:
                embree.cast(scene_)      # the build happens on the first cast
            paths["open3d Embree: build + cast"] = lambda: embree.frames(vertices)
            paths["open3d Embree: cast only"] = lambda: [embree.cast(s) for s in built]
            ids, depth = embree.frames(vertices)
            checks["open3d Embree"] = agreement(our_faces, ids)
            both = (our_faces >= 0) & (ids == our_faces)
            checks["open3d Embree"]["max_depth_difference_mm"] = float(
                1000 * np.abs(depth[both] - ours.depth.numpy()[both]).max()) if both.any() else None
        gl = _optional("moderngl", lambda: GLFaceIds(faces, len(vertices[0]), K.numpy(), size), notes)
        if gl is not None:
            notes.setdefault("moderngl renderer", gl.renderer)
            paths["moderngl EGL (" + gl.renderer.split(" (")[0] + "): draw + readback"] = lambda: gl.frames(vertices)
            checks["moderngl"] = agreement(our_faces, gl.frames(vertices))
        names = list(paths)
        medians = alternating_medians([paths[name] for name in names], args.repeats)
        results["sizes"][size] = {"ms_per_frame": {name: round(1000 * seconds / args.frames, 2)
                                                   for name, seconds in zip(names, medians)},
                                  "face_agreement": checks}
    results["notes"] = notes
    _print_floor(results, args)
    return results


def _optional(package, make, notes):
    """make() if `package` imports and works; else None, with the reason in notes[package]."""
    try:
        __import__(package)
    except ImportError as error:
        notes[package] = f"{OPTIONAL_MISSING} ({error})"
        print(f"{package}: {notes[package]}: skipped")
        return None
    try:
        return make()
    except Exception as error:   # a headless context may not be had on this machine: say why, go on
        notes[package] = f"failed: {type(error).__name__}: {str(error).strip().splitlines()[0] if str(error) else ''}"
        print(f"{package}: {notes[package]}: skipped")
        return None


def _print_floor(results, args):
    sizes = list(results["sizes"])
    names = list(dict.fromkeys(name for size in sizes for name in results["sizes"][size]["ms_per_frame"]))
    print(f"ms per frame (median of {args.repeats} alternating rounds of {args.frames} frames)")
    print(f"{'path':<58}" + "".join(f"{f'{s}x{s}':>12}" for s in sizes))
    for name in names:
        cells = [results["sizes"][s]["ms_per_frame"].get(name) for s in sizes]
        print(f"{name:<58}" + "".join(f"{'-' if c is None else f'{c:.2f}':>12}" for c in cells))
    for size in sizes:
        for other, check in results["sizes"][size]["face_agreement"].items():
            extra = (f", max depth difference where they agree {check['max_depth_difference_mm']:.4f} mm"
                     if check.get("max_depth_difference_mm") is not None else "")
            print(f"{size}x{size} face ids, ours vs {other}: {100 * check['agree_on_both']:.3f}% agree where both "
                  f"cover, {100 * check['agree_on_either']:.3f}% over the pixels either covers "
                  f"(coverage IoU {check['coverage_iou']:.4f}, {check['covered_pixels']} pixels){extra}")
    for package, note in results["notes"].items():
        print(f"{package}: {note}")


# ----------------------------------------------------------------------------------------------
# part 2: the fit's steps, piece by piece


def _ranged(name, function):
    from torch.profiler import record_function

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        with record_function(RANGE + name):
            return function(*args, **kwargs)
    return wrapper


@contextlib.contextmanager
def instrumented(problem):
    """record_function ranges around the pieces of a fit step (monkeypatched, undone on exit)."""
    import torch

    from pipeline.fit import avatar, energy, losses, stage_run
    from pipeline.fit.surface_regularisers import SurfaceRegularisers
    from pipeline.render import fused, renderer

    terms = [(owner, f"{term}_loss", _ranged(f"loss: {term}", getattr(owner, f"{term}_loss")))
             for owner in (losses, SurfaceRegularisers) for term in LOSS_TERMS if hasattr(owner, f"{term}_loss")]
    if problem.perceptual is not None:
        terms.append((problem, "perceptual", _ranged("loss: perceptual", problem.perceptual)))
    patches = terms + [
        (renderer, "FUSED", dataclasses.replace(
            renderer.FUSED, rasterize=_ranged("rasterize", renderer.FUSED.rasterize),
            fragments=_ranged("fragments", renderer.FUSED.fragments),
            interpolate_many=_ranged("interpolation", renderer.FUSED.interpolate_many),
            vertex_normals=_ranged("normals and tangents", renderer.FUSED.vertex_normals),
            uv_tangents=_ranged("normals and tangents", renderer.FUSED.uv_tangents),
            perturbed_normal=_ranged("shading", renderer.FUSED.perturbed_normal),
            shadow_visibility=_ranged("shadow map", renderer.FUSED.shadow_visibility),
            lit_colour=_ranged("shading", renderer.FUSED.lit_colour),
            composite=_ranged("composite", renderer.FUSED.composite),
            antialias=_ranged("antialias", renderer.FUSED.antialias))),
        (fused, "rasterize", _ranged("rasterize (shadow map)", fused.rasterize)),   # shadow_visibility's own
        (renderer, "sample_texture", _ranged("texture lookup", renderer.sample_texture)),
        (energy, "render", _ranged("render (other)", energy.render)),
        (stage_run, "batch_energy", _ranged("losses (other)", stage_run.batch_energy)),
        (avatar.Avatar, "posed", _ranged("posing", avatar.Avatar.posed)),
        (avatar.Avatar, "posed_coarse", _ranged("posing", avatar.Avatar.posed_coarse)),
        (stage_run.StageRun, "_lazy_step", _ranged("optimiser", stage_run.StageRun._lazy_step)),
        (stage_run.StageRun, "step", _ranged("step", stage_run.StageRun.step)),
        (torch.autograd, "backward", _ranged("backward", torch.autograd.backward)),
    ]
    saved = [(owner, name, vars(owner)[name]) for owner, name, _ in patches]
    try:
        for owner, name, value in patches:
            setattr(owner, name, value)
        yield
    finally:
        for owner, name, value in saved:
            setattr(owner, name, value)


def _duration_us(event):
    return event.time_range.end - event.time_range.start


def _innermost_range(event):
    parent = event.cpu_parent
    while parent is not None and not parent.name.startswith(RANGE):
        parent = parent.cpu_parent
    return parent


def _in_backward_node(event):
    parent = event.cpu_parent
    while parent is not None:
        if parent.name.startswith("autograd::engine::evaluate_function"):
            return True
        parent = parent.cpu_parent
    return False


def attribute(events):
    """({range name: [forward us, backward us]}, [each step's us]) from profiler events."""
    times = collections.defaultdict(lambda: [0.0, 0.0])
    forward_range = {}
    steps = []
    # in order of starting: an operator that makes no autograd node records the number the next
    # node will take, so the last forward event with a number is the one that made its node
    events = sorted(events, key=lambda event: event.time_range.start)
    for event in events:
        if event.name.startswith(RANGE):
            name = event.name[len(RANGE):]
            if name == "step":
                steps.append(_duration_us(event))
            times[name][0] += _duration_us(event)
            outer = _innermost_range(event)
            if outer is not None:   # exclusive time: nested ranges are their own
                times[outer.name[len(RANGE):]][0] -= _duration_us(event)
        elif event.sequence_nr >= 0 and not event.name.startswith("autograd::engine::evaluate_function") \
                and not _in_backward_node(event):
            outer = _innermost_range(event)
            forward_range[event.sequence_nr] = outer.name[len(RANGE):] if outer is not None else None
    for event in events:
        if event.name.startswith("autograd::engine::evaluate_function") and not _in_backward_node(event):
            name = forward_range.get(event.sequence_nr)
            if name in COLUMNS:
                times[name][1] += _duration_us(event)
                times["backward"][0] -= _duration_us(event)   # what stays in "backward" is unattributed
    return dict(times), steps


def profile_kind(problem, stage, kind, steps):
    """One kind of step: warm-up, `steps` plain, `steps` profiled, `steps` plain again, every phase
    on the same batches. (plain ms of each step, profiled ms of each step, {range: [fwd ms, bwd ms]
    per profiled step}, frames per step)."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    from pipeline.fit.checkpoint import FitState
    from pipeline.fit.stage_run import StageRun

    state = FitState.fresh(problem.settings.schedule(), "on" if kind.endswith(" shadows") else "off")
    generator = torch.Generator().manual_seed(0)
    run = StageRun(problem, stage, state, generator)
    if not run.has_work:
        return None
    run.step()                                       # warm-up: the optimiser's state, first allocations
    order, random_state = list(state.order), generator.get_state()
    frames = []

    def same_batches():
        state.order = list(order)
        generator.set_state(random_state)

    def batch_frames():   # as StageRun.next_batch draws them
        if stage.full_batch:
            return len(problem.frames)
        return min(problem.settings.batch_size, len(state.order) or len(problem.frames))

    def plain_steps():
        same_batches()
        durations = []
        for _ in range(steps):
            frames.append(batch_frames())
            begin = time.perf_counter()
            run.step()
            durations.append(1000 * (time.perf_counter() - begin))
        return durations

    plain = plain_steps()
    same_batches()
    with instrumented(problem), profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(steps):
            run.step()
    plain += plain_steps()
    times, profiled = attribute(prof.events())
    per_step = {name: [fwd / 1000 / steps, bwd / 1000 / steps] for name, (fwd, bwd) in times.items()}
    return plain, [us / 1000 for us in profiled], per_step, statistics.fmean(frames)


def summarise(per_step, total_ms):
    """The summary columns (ms per step, forward + its backward) from the ranges."""
    summary = dict.fromkeys(SUMMARY, 0.0)
    for name, (fwd, bwd) in per_step.items():
        if name in COLUMNS:
            summary[COLUMNS[name]] += fwd + bwd
    summary["rest"] = total_ms - sum(summary.values())
    return summary


def fit_profile(args):
    """Part 2: {preset: {kind: figures}}."""
    import torch

    from pipeline.fit import fitting
    from pipeline.fit.schedule import step_kind

    results = {}
    for preset in args.presets.split(","):
        start = time.perf_counter()
        problem = fitting._set_up(Path(args.sequence), fitting.FitJob(preset=preset, device="cpu"),
                                  {"max_frames": args.max_frames}).problem
        settings = problem.settings
        print(f"\n== fit profile: preset {preset}, {len(problem.frames)} frames at {problem.clip.width}x"
              f"{problem.clip.height}, batches of {settings.batch_size} (alignment: every frame, unsubdivided "
              f"mesh), texture {settings.texture_size}, perceptual {problem.perceptual_name}; problem built in "
              f"{time.perf_counter() - start:.0f} s; per kind: one warm-up step, then {args.steps} plain, {args.steps} "
              f"profiled and {args.steps} plain steps on the same batches")
        saved = copy.deepcopy(problem.avatar.state_dict())
        stages = {stage.name: stage for stage in settings.schedule()}
        kinds = {}
        try:
            for kind in args.kinds.split(","):
                stage = stages[kind.split(" ")[0]]
                if str(step_kind(stage, kind.endswith(" shadows"))) != kind:
                    continue
                begin = time.perf_counter()
                measured = profile_kind(problem, stage, kind, args.steps)
                problem.avatar.load_state_dict(saved)
                for parameter in problem.avatar.parameters():
                    parameter.grad = None
                if measured is None:
                    print(f"{kind}: nothing to move, skipped")
                    continue
                plain, profiled, per_step, frames = measured
                total = statistics.fmean(profiled)
                kinds[kind] = {"frames_per_step": round(frames, 1),
                               "unprofiled_ms_per_step": round(statistics.fmean(plain), 1),
                               "profiled_ms_per_step": round(total, 1),
                               "unprofiled_ms_each_step": [round(v) for v in plain],
                               "profiled_ms_each_step": [round(v) for v in profiled],
                               "summary_ms": {k: round(v, 1) for k, v in summarise(per_step, total).items()},
                               "ranges_ms": {name: {"forward": round(fwd, 2), "backward": round(bwd, 2)}
                                             for name, (fwd, bwd) in sorted(per_step.items())},
                               "wall_seconds": round(time.perf_counter() - begin, 1)}
                print(f"  {kind}: {frames:.0f} frames per step; ms per step plain {[round(v) for v in plain]}, "
                      f"profiled {[round(v) for v in profiled]} ({time.perf_counter() - begin:.0f} s)", flush=True)
        finally:
            problem.avatar.load_state_dict(saved)
        results[preset] = {"frames": len(problem.frames), "resolution": problem.clip.width,
                           "batch_size": settings.batch_size, "kinds": kinds}
        _print_fit(preset, results[preset])
        del problem
    return results


def _print_fit(preset, result):
    kinds = result["kinds"]
    print(f"\n{preset}: ms per step, each piece's forward with the backward it caused (profiled steps)")
    header = f"{'kind':<29}" + "".join(f"{SUMMARY_TITLES[c]:>18}" for c in SUMMARY) + f"{'profiled':>10}{'plain':>8}"
    print(header)
    for kind, figures in kinds.items():
        total = figures["profiled_ms_per_step"]
        cells = "".join(f"{f'{v:.0f} ({100 * v / total:.0f}%)':>18}" for v in figures["summary_ms"].values())
        print(f"{kind:<29}{cells}{total:>10.0f}{figures['unprofiled_ms_per_step']:>8.0f}")
    names = [n for n in COLUMNS if any(n in f["ranges_ms"] for f in kinds.values())] + ["backward"]
    print(f"\n{preset}: the pieces, forward / backward ms per step ('backward' alone: backward time that "
          "maps to no piece)")
    print(f"{'piece':<30}" + "".join(f"{SHORT.get(kind, kind):>16}" for kind in kinds))
    for name in names:
        cells = []
        for figures in kinds.values():
            piece = figures["ranges_ms"].get(name)
            cells.append("-" if piece is None else
                         f"{piece['forward']:.0f}" if name == "backward" else
                         f"{piece['forward']:.1f} / {piece['backward']:.1f}")
        print(f"{name:<30}" + "".join(f"{cell:>16}" for cell in cells))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", nargs="?", help="a sequence folder with init.npz (part 2)")
    parser.add_argument("--presets", default="fast,full")
    parser.add_argument("--kinds", default=",".join(KINDS), help="step kinds to profile (comma separated)")
    parser.add_argument("--max-frames", type=int, default=30)
    parser.add_argument("--steps", type=int, default=3, help="profiled (and plainly timed) steps per kind")
    parser.add_argument("--frames", type=int, default=8, help="frames of the native-floor renders")
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 448])
    parser.add_argument("--repeats", type=int, default=5, help="alternating rounds of the native-floor paths")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--skip-floor", action="store_true")
    parser.add_argument("--skip-fit", action="store_true")
    parser.add_argument("--out", help="write the figures as JSON here")
    args = parser.parse_args()
    from pipeline.threads import configure_threads

    threads = configure_threads(args.threads)
    import torch

    print(f"torch {torch.__version__}, {threads['threads']} thread(s), OMP_WAIT_POLICY {threads['wait_policy']}, "
          f"cores allowed {sorted(os.sched_getaffinity(0))}")
    started = time.perf_counter()
    results = {"command": " ".join(sys.argv), "threads": threads, "cores": sorted(os.sched_getaffinity(0))}
    if not args.skip_floor:
        results["native_floor"] = native_floor(args)
    if not args.skip_fit:
        if args.sequence is None:
            print("\nfit profile: no sequence folder given: skipped")
        else:
            results["fit_profile"] = fit_profile(args)
    results["seconds"] = round(time.perf_counter() - started, 1)
    print(f"\n{results['seconds']:.0f} s in all")
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
