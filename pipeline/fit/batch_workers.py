"""Both cores at work: other processes that each take a share of every batch's frames.

A fit's step is many small operations, so a second torch thread buys next to nothing (docs/
performance.md). Instead, `BatchWorkers` starts processes that build the same fit problem and
share the avatar's parameters through shared memory (the fit's optimiser updates them in place,
so every process always sees the current values). For each step the batch is split: the fit
takes the first part, each worker one of the others; a part's energy and gradients are
weighted by its share of the batch, as StageRun.energy weights its chunks, and the workers'
gradients are added to the fit's. The terms over all frames (temporal, regularisers) are
computed in every part at its share, so they add up to one whole.

The texture regularisers draw random offsets: each worker draws them from a seed the fit's own
generator gives it, so a fit with workers repeats itself bit for bit, but differs from one
without (it is the same energy, drawn otherwise). A worker that fails is one FitError line.
"""
from __future__ import annotations

import signal

import torch
import torch.multiprocessing as multiprocessing

from .avatar import SWITCHES
from .schedule import StageSpec


class BatchWorkers:
    """`count` worker processes over the same problem as `problem` (built from `recipe`: the
    arguments of problem.build_problem, as fit() built it)."""

    def __init__(self, problem, recipe: dict, count: int):
        self.problem, self.count = problem, count
        parameters = dict(problem.avatar.named_parameters())
        parameters.update((name, getattr(problem.avatar, name)) for name in SWITCHES)   # the light's switches too
        for parameter in parameters.values():
            parameter.data.share_memory_()
        # the keypoint anchor too: a frame started again from its neighbours moves its anchor (lost_frames.py)
        parameters["anchor_keypoints"] = problem.anchor_keypoints.share_memory_()
        for held in ("size_prior", "depth_prior"):     # and the size and depth held, set after the alignment
            if held in problem.term_data:
                parameters[held] = problem.term_data[held].share_memory_()
        context = multiprocessing.get_context("spawn")
        self.connections, self.processes = [], []
        for _ in range(count):
            ours, theirs = context.Pipe()
            process = context.Process(target=_serve, args=(theirs, recipe, parameters), daemon=True)
            process.start()
            theirs.close()          # ours alone: a worker that dies ends the pipe (EOFError), no hang
            self.connections.append(ours)
            self.processes.append(process)
        for connection in self.connections:
            self._receive(connection)       # "ready": the worker has built its problem

    def send(self, connection, stage: StageSpec, frames, chunk_size, batch_size, shadows, seed, progress=0.0):
        """Ask a worker for the energy of `frames` (a part of a batch of `batch_size` frames), in
        chunks of `chunk_size`, each weighted by its share of the batch, `progress` into the stage."""
        connection.send(("energy", stage, frames.cpu().numpy(), chunk_size, batch_size, shadows, seed, progress))

    def collect(self, connection) -> tuple:
        """(loss, terms) of a part sent to `connection`, weighted by its share of the batch; its
        gradients are added to the fit's."""
        loss, terms, gradients = self._receive(connection)
        for name, parameter in self.problem.avatar.named_parameters():
            if name not in gradients:
                continue
            gradient = torch.as_tensor(gradients[name], device=parameter.device)
            parameter.grad = gradient if parameter.grad is None else parameter.grad + gradient
        return loss, terms

    def _receive(self, connection):
        from .problem import FitError

        try:
            kind, *payload = connection.recv()
        except (EOFError, ConnectionError):
            self.close()
            raise FitError("a batch worker process died: fit again with --threads 1") from None
        if kind == "error":
            self.close()
            raise FitError(f"a batch worker failed: {payload[0]}")
        return payload if kind == "energy" else None

    def close(self):
        for connection in self.connections:
            try:
                connection.send(("stop",))
            except (OSError, ValueError):
                pass
        for process in self.processes:
            process.join(timeout=5)
            if process.is_alive():
                process.kill()
        self.connections, self.processes = [], []


def _serve(connection, recipe, parameters):
    """A worker's loop: build the problem, take the fit's parameters, answer energy requests."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # Ctrl-C stops the fit, which stops us
    torch.set_num_threads(1)
    try:
        from .problem import build_problem
        from .stage_run import chunked_energy

        problem = build_problem(**recipe)
        own = dict(problem.avatar.named_parameters())
        for name, shared in parameters.items():
            if name == "anchor_keypoints":
                problem.anchor_keypoints = shared
            elif name in ("size_prior", "depth_prior"):
                problem.term_data[name] = shared
            elif name in own:
                own[name].data = shared
            else:   # a switch (a buffer)
                setattr(problem.avatar, name, shared)
        connection.send(("ready",))
        while True:
            message = connection.recv()
            if message[0] == "stop":
                return
            _, stage, frames, chunk_size, batch_size, shadows, seed, progress = message
            for parameter in own.values():
                parameter.grad = None
            generator = torch.Generator().manual_seed(seed)
            loss, terms = chunked_energy(problem, stage, torch.as_tensor(frames, device=problem.device), chunk_size,
                                         batch_size, shadows, generator, progress=progress)
            gradients = {name: parameter.grad.cpu().numpy() for name, parameter in own.items()
                         if parameter.grad is not None}
            connection.send(("energy", loss, terms, gradients))
    except (EOFError, KeyboardInterrupt):
        return
    except Exception as error:  # reported to the fit as one line
        connection.send(("error", f"{type(error).__name__}: {error}"))
