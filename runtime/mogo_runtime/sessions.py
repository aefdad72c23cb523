"""onnxruntime session settings shared by every graph the runtime opens."""
from __future__ import annotations


def session_options(threads: int):
    """Options for sitting inside a host application: few threads, one graph at a time."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    if threads > 1:
        # spinning workers fight the host's own threads for the cores: 2 spinning threads measured 2-3x slower
        # than 1 thread on a busy 2-core machine, and 52% slower than 2 threads without spinning
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return opts
