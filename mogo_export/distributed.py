"""Training on several processes or GPUs: `mogo-export train` under torchrun, with DistributedDataParallel.

    torchrun --standalone --nproc_per_node 2 -m mogo_export.cli train --data ... --out ... --preset tiny

A process group is set up only when torchrun launched the process (WORLD_SIZE > 1, or LOCAL_RANK set): nccl with
one GPU per process where CUDA is available, gloo on the CPU otherwise. A plain `mogo-export train` gets
`SINGLE`, on which every operation here does nothing, so it trains exactly as it always did.

The scheme keeps a run with N processes on the curve of one process with the same global batch:
- every process draws the preset's whole batch from the same seeded RNGs, as one process would, and trains on
  its own slice of it (`Group.shard`), so the RNG states, and with them the checkpoints, do not depend on the
  number of processes: a run resumes on another count;
- DistributedDataParallel averages gradients, and the losses are scaled so that the average is the gradient of
  the global batch's mean; the VQ's codebooks learn from counts and sums over every slice
  (`vq.ResidualQuantizer.sync`), so weights, buffers and optimiser state stay the same on every process;
- rank 0 alone validates, prints and writes files; the others wait at a barrier until a checkpoint is whole.
What a split batch cannot reproduce: per-element randomness (dropout and the transformer's condition dropout draw
other masks for slices than for the whole batch), and float32 rounding (sums run in another order, and the VQ's
nearest-code choices and Adam grow the difference as a change of torch's thread count does); in float64 without
dropout the curves agree to 1e-15 (tests/export/test_distributed.py; README, "Training on several processes or
GPUs").
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Iterator

import numpy as np
import torch
import torch.distributed as dist


def launched() -> bool:
    """True in a process that torchrun started (it sets WORLD_SIZE, RANK, LOCAL_RANK, MASTER_ADDR/PORT)."""
    return int(os.environ.get("WORLD_SIZE", "1")) > 1 or "LOCAL_RANK" in os.environ


@dataclass(frozen=True)
class Group:
    """This process's place in a training run: rank `rank` of `world` processes, training on `device`."""

    rank: int = 0
    world: int = 1
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def shard(self, batch: int, what: str) -> slice:
        """This process's rows of a global batch of `batch`."""
        if batch % self.world:
            raise ValueError(f"{what}: the global batch of {batch} does not divide among {self.world} processes; "
                             f"use a process count that divides it")
        n = batch // self.world
        return slice(self.rank * n, (self.rank + 1) * n)

    def part(self, n: int) -> slice:
        """This process's share of `n` items that need not divide evenly (the first n % world get one more)."""
        q, r = divmod(n, self.world)
        start = self.rank * q + min(self.rank, r)
        return slice(start, start + q + (self.rank < r))

    def wrap(self, module: torch.nn.Module) -> torch.nn.Module:
        """The module whose forward computes the loss, under DistributedDataParallel when there are several
        processes. No buffers are broadcast: the VQ keeps its codebooks equal on every process itself."""
        if self.world == 1:
            return module
        ids = [self.device.index] if self.device.type == "cuda" else None
        return torch.nn.parallel.DistributedDataParallel(module, device_ids=ids, forward_sync_buffers=False)

    def sum(self, t: torch.Tensor) -> torch.Tensor:
        """The sum over every process of `t` (not changed; `t` itself with one process)."""
        if self.world == 1:
            return t
        t = t.detach().clone()
        dist.all_reduce(t)
        return t

    def mean(self, t: torch.Tensor) -> torch.Tensor:
        return t if self.world == 1 else self.sum(t) / self.world

    def cat(self, t: torch.Tensor) -> torch.Tensor:
        """Every process's `t` (the same shape everywhere) joined along dim 0 in rank order: the rows of the
        global batch in the order one process holds them."""
        if self.world == 1:
            return t
        parts = [torch.empty_like(t) for _ in range(self.world)]
        dist.all_gather(parts, t.contiguous())
        return torch.cat(parts)

    def barrier(self) -> None:
        if self.world > 1:
            dist.barrier(device_ids=[self.device.index] if self.device.type == "cuda" else None)

    @contextmanager
    def main_first(self) -> Iterator[None]:
        """Rank 0 runs the block first (and writes what it caches); the others run it after, reading that."""
        if not self.is_main:
            self.barrier()
        yield
        if self.is_main:
            self.barrier()

    def fork_torch_rng(self, seed: int, step: int) -> None:
        """Give ranks other than 0 a torch RNG stream of their own. The transformer's only torch randomness is
        dropout and condition dropout; with one shared stream, sample i of every slice would drop its caption
        together with sample i of every other slice. Rank 0 keeps the stream its checkpoints record."""
        if self.rank:
            torch.manual_seed(int(np.random.SeedSequence([seed, step, self.rank]).generate_state(1)[0]))


SINGLE = Group()


def native_bf16(device: torch.device, cpu_flags: str | None = None) -> bool:
    """Whether `device` computes bfloat16 natively: a CUDA device that says so, or a CPU whose flags (Linux's
    /proc/cpuinfo, or `cpu_flags`) list AVX-512 BF16, AMX BF16 or ARM's BF16. Elsewhere torch emulates bf16, slower
    than float32."""
    if device.type == "cuda":
        return torch.cuda.is_bf16_supported()
    if device.type != "cpu":
        return False
    if cpu_flags is None:
        try:
            with open("/proc/cpuinfo") as f:
                cpu_flags = f.read()
        except OSError:
            return False
    words = set(cpu_flags.lower().split())
    return bool(words & {"avx512_bf16", "amx_bf16", "bf16"})


@contextmanager
def session(timeout_minutes: float = 120) -> Iterator[Group]:
    """The Group of this process: a process group for its lifetime when torchrun started it, else SINGLE.

    The timeout is long because rank 0 alone embeds captions and extracts tokens between the two phases while
    the others wait at a barrier (minutes on real HumanML3D); torchrun ends every process when one fails."""
    if not launched():
        yield SINGLE
        return
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if torch.cuda.is_available():
        if local >= torch.cuda.device_count():
            raise ValueError(f"process {local} on this node, but only {torch.cuda.device_count()} GPUs: start at "
                             f"most that many (--nproc_per_node), or hide them (CUDA_VISIBLE_DEVICES=) for CPUs")
        device = torch.device("cuda", local)
        torch.cuda.set_device(device)
        dist.init_process_group("nccl", timeout=timedelta(minutes=timeout_minutes), device_id=device)
    else:
        device = torch.device("cpu")
        dist.init_process_group("gloo", timeout=timedelta(minutes=timeout_minutes))
    try:
        yield Group(rank=dist.get_rank(), world=dist.get_world_size(), device=device)
    finally:
        dist.destroy_process_group()
