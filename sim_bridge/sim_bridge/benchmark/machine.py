"""The machine a round ran on, for its record. Drake's solver rounds differently on
different CPU types and a clutter round amplifies it (a replay on another CPU type
can take other attempts: doc/benchmark-speed.md), so a round is reproducible on its
machine type only; its record says which that was."""

from __future__ import annotations

import functools
import os
import platform


@functools.lru_cache(maxsize=1)
def machine_name() -> str:
    """'<CPU model>, <n> cores', e.g. 'AMD EPYC, 2 cores' (the CPU model from
    /proc/cpuinfo where there is one, else what `platform` says)."""
    model = ""
    try:
        with open("/proc/cpuinfo") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "")
    except OSError:
        pass
    model = model or platform.processor() or platform.machine() or "unknown CPU"
    return f"{model}, {os.cpu_count()} cores"
