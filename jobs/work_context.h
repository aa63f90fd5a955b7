// Accounting of work for the profiler: every parallel loop records, per chunk,
// the thread CPU time it used into the WorkContext that was current on the thread
// that started the loop (the pass running it), and optionally a trace slice.
// This is how the scheduler attributes CPU time to passes that run concurrently
// on a shared work-stealing pool.
#pragma once

#include <atomic>
#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

namespace fg::jobs {

// Monotonic wall clock and per-thread CPU clock, nanoseconds.
std::int64_t wallNanos();
std::int64_t threadCpuNanos();
// Small stable id of the calling worker thread, for traces.
int threadSlot();

struct TraceSlice {
    std::string name;
    std::string category;  // "pass" or "chunk"
    int thread = 0;
    std::int64_t beginNs = 0;
    std::int64_t endNs = 0;
    std::int64_t items = 0;
};

// Collects trace slices from all threads when enabled; cheap no-op otherwise.
class TraceRecorder {
public:
    static TraceRecorder& instance();
    void setEnabled(bool enabled) { enabled_.store(enabled, std::memory_order_relaxed); }
    bool enabled() const { return enabled_.load(std::memory_order_relaxed); }
    void record(TraceSlice slice);
    std::vector<TraceSlice> take();

private:
    std::atomic<bool> enabled_{false};
    std::mutex mutex_;
    std::vector<TraceSlice> slices_;
};

struct WorkContext {
    std::string label;
    std::atomic<std::int64_t> chunkCpuNs{0};
    std::atomic<std::int64_t> chunks{0};
};

// The context of the pass whose code runs on this thread, or nullptr.
WorkContext* currentContext();

class ScopedContext {
public:
    explicit ScopedContext(WorkContext* ctx);
    ~ScopedContext();
    ScopedContext(const ScopedContext&) = delete;
    ScopedContext& operator=(const ScopedContext&) = delete;

private:
    WorkContext* previous_;
};

// Thread CPU nanoseconds spent in chunks on this thread so far; the scheduler
// subtracts it from a pass body's own CPU time so nothing is counted twice.
std::int64_t chunkCpuOnThisThread();

// Times one chunk on the current thread and books it to `owner`.
class ChunkTimer {
public:
    ChunkTimer(WorkContext* owner, std::int64_t items);
    ~ChunkTimer();
    ChunkTimer(const ChunkTimer&) = delete;
    ChunkTimer& operator=(const ChunkTimer&) = delete;

private:
    WorkContext* owner_;
    std::int64_t items_;
    std::int64_t cpu0_;
    std::int64_t wall0_;
    WorkContext* previous_;
};

}  // namespace fg::jobs
