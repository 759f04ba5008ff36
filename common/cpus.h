#pragma once

// How many CPUs this process may run on: the default thread count of every
// part that runs a pool of threads (the renderer's --threads 0, the embedded
// farm's per-worker share, dofarm-train's intra-op threads).

namespace dofarm {

// The CPUs in this process's affinity mask (sched_getaffinity), at least 1.
// Under Slurm, or under `taskset`, that is the allocation, not the machine:
// std::thread::hardware_concurrency() counts every hardware thread of the
// machine and would oversubscribe a job given part of a node.
int cpus_available();

}  // namespace dofarm
