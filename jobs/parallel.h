// The one thin layer over oneTBB. Everything else in fluxgraph expresses its
// parallelism through these functions:
//  - parallelFor: a loop over an index range [0, n) in chunks of `grain` items;
//  - deterministicReduce: per-block accumulators over fixed blocks, merged in
//    block order, so a floating-point sum is bit-identical for any thread count;
//  - PerWorker: scratch state owned by one worker thread at a time, reused
//    across the chunks that thread runs (no allocation per chunk);
//  - ThreadLimit: caps the worker count for a scope (the --threads option);
//  - TaskGraph: a dependency graph of tasks (the pass scheduler's flow graph).
// Chunks are booked to the calling pass's WorkContext for the profiler.
// Every chunk and task runs in one floating-point mode (useDeterministicFloatMode).
#pragma once

#include "jobs/work_context.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <cstddef>
#include <functional>
#include <memory>
#include <vector>

namespace fg::jobs {

// Sets the calling thread's SSE floating-point mode to flush subnormal results
// and read subnormal inputs as zero (FTZ and DAZ). A thread's mode is whatever
// the code it last ran left behind (libraries set it in the threads they run
// on), so without this a result that passes through a subnormal could differ
// between runs, processes and thread counts. Every chunk and task body sets it
// first; it costs one control-register write.
void useDeterministicFloatMode();

struct IndexRange {
    std::size_t begin = 0;
    std::size_t end = 0;
    std::size_t size() const { return end - begin; }
};

// body(IndexRange) is called for disjoint chunks covering [0, n), each at most
// `grain` items long. Chunk boundaries depend only on n and grain.
template <class Body>
void parallelForChunks(std::size_t n, std::size_t grain, Body&& body) {
    if (n == 0) return;
    if (grain == 0) grain = 1;
    WorkContext* owner = currentContext();
    const std::size_t chunks = (n + grain - 1) / grain;
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, chunks, 1),
        [&](const tbb::blocked_range<std::size_t>& r) {
            useDeterministicFloatMode();
            for (std::size_t c = r.begin(); c != r.end(); ++c) {
                const IndexRange chunk{c * grain, std::min(n, (c + 1) * grain)};
                ChunkTimer timer(owner, static_cast<std::int64_t>(chunk.size()));
                body(chunk);
            }
        },
        tbb::simple_partitioner());
}

// body(i) for every i in [0, n).
template <class Body>
void parallelFor(std::size_t n, std::size_t grain, Body&& body) {
    parallelForChunks(n, grain, [&](IndexRange r) {
        for (std::size_t i = r.begin; i != r.end; ++i) body(i);
    });
}

// The `blocks` contiguous blocks deterministicReduce splits [0, n) into: block b
// is [b * per, (b + 1) * per) clipped to n, per = ceil(n / blocks); trailing
// blocks may be empty. body(b, IndexRange) runs once per block, in parallel.
// For callers that keep one accumulator per block across several calls (e.g.
// across batches) and merge them in block order at the end.
template <class Body>
void parallelForBlocks(std::size_t n, std::size_t blocks, Body&& body) {
    if (blocks == 0 || n == 0) return;
    const std::size_t per = (n + blocks - 1) / blocks;
    parallelForChunks(blocks, 1, [&](IndexRange r) {
        for (std::size_t b = r.begin; b != r.end; ++b) {
            const IndexRange items{std::min(n, b * per), std::min(n, (b + 1) * per)};
            if (items.size() > 0) body(b, items);
        }
    });
}

// Splits [0, n) into `blocks` contiguous blocks (fewer if n is small), reduces
// each into a fresh accumulator made by init(), calling body(acc, IndexRange),
// and merges them with merge(total, part) in block order on the calling thread.
// The block count is fixed by the caller, never by the thread count, which is
// what makes the result reproducible.
template <class Acc, class Init, class Body, class Merge>
Acc deterministicReduce(std::size_t n, std::size_t blocks, Init&& init, Body&& body, Merge&& merge) {
    if (blocks == 0) blocks = 1;
    blocks = std::max<std::size_t>(1, std::min(blocks, n));
    std::vector<std::unique_ptr<Acc>> parts(blocks);
    const std::size_t per = (n + blocks - 1) / std::max<std::size_t>(blocks, 1);
    parallelForChunks(blocks, 1, [&](IndexRange r) {
        for (std::size_t b = r.begin; b != r.end; ++b) {
            parts[b] = std::make_unique<Acc>(init());
            const IndexRange items{std::min(n, b * per), std::min(n, (b + 1) * per)};
            if (items.size() > 0) body(*parts[b], items);
        }
    });
    Acc total = init();
    for (auto& part : parts)
        if (part) merge(total, *part);
    return total;
}

// One T per worker thread that asks for it, made on first use and kept for
// the object's lifetime. A chunk body takes local() once and must not wait on
// other parallel work while it holds it (a waiting thread may run another chunk
// of the same loop, which would get the same object). Nothing a result depends
// on may be kept in it between chunks: which worker runs a chunk varies.
template <class T>
class PerWorker {
public:
    T& local() { return slots_.local(); }

private:
    tbb::enumerable_thread_specific<T> slots_;
};

// Number of worker threads the pool currently allows.
int maxThreads();
// Hardware concurrency of the machine.
int hardwareThreads();

// Caps parallelism to `threads` for its lifetime (0 = hardware default).
class ThreadLimit {
public:
    explicit ThreadLimit(int threads);
    ~ThreadLimit();
    ThreadLimit(const ThreadLimit&) = delete;
    ThreadLimit& operator=(const ThreadLimit&) = delete;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

// A dependency graph of tasks run on the shared pool: a task starts once all of
// its predecessors have finished; independent tasks run concurrently. If a task
// throws, tasks not yet started are skipped and run() rethrows the first error.
class TaskGraph {
public:
    TaskGraph();
    ~TaskGraph();
    TaskGraph(const TaskGraph&) = delete;
    TaskGraph& operator=(const TaskGraph&) = delete;

    int addTask(std::function<void()> task);
    void addEdge(int from, int to);
    void run();

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace fg::jobs
