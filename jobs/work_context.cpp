#include "jobs/work_context.h"

#include <ctime>
#include <utility>

namespace fg::jobs {

namespace {
thread_local WorkContext* tCurrent = nullptr;
thread_local std::int64_t tChunkCpu = 0;
// Depth of nested chunks on this thread: only the outermost one books CPU time,
// since it already contains the inner ones.
thread_local int tChunkDepth = 0;
std::atomic<int> gNextSlot{0};
thread_local int tSlot = -1;

std::int64_t readClock(clockid_t id) {
    timespec ts{};
    clock_gettime(id, &ts);
    return static_cast<std::int64_t>(ts.tv_sec) * 1000000000ll + ts.tv_nsec;
}
}  // namespace

std::int64_t wallNanos() { return readClock(CLOCK_MONOTONIC); }
std::int64_t threadCpuNanos() { return readClock(CLOCK_THREAD_CPUTIME_ID); }

int threadSlot() {
    if (tSlot < 0) tSlot = gNextSlot.fetch_add(1);
    return tSlot;
}

TraceRecorder& TraceRecorder::instance() {
    static TraceRecorder recorder;
    return recorder;
}

void TraceRecorder::record(TraceSlice slice) {
    std::lock_guard lock(mutex_);
    slices_.push_back(std::move(slice));
}

std::vector<TraceSlice> TraceRecorder::take() {
    std::lock_guard lock(mutex_);
    return std::exchange(slices_, {});
}

WorkContext* currentContext() { return tCurrent; }

ScopedContext::ScopedContext(WorkContext* ctx) : previous_(tCurrent) { tCurrent = ctx; }
ScopedContext::~ScopedContext() { tCurrent = previous_; }

std::int64_t chunkCpuOnThisThread() { return tChunkCpu; }

ChunkTimer::ChunkTimer(WorkContext* owner, std::int64_t items)
    : owner_(owner), items_(items), cpu0_(threadCpuNanos()), wall0_(0), previous_(tCurrent) {
    // Nested loops started inside this chunk belong to the same pass.
    tCurrent = owner;
    ++tChunkDepth;
    if (owner_ && TraceRecorder::instance().enabled()) wall0_ = wallNanos();
}

ChunkTimer::~ChunkTimer() {
    tCurrent = previous_;
    const bool outermost = --tChunkDepth == 0;
    const std::int64_t cpu = outermost ? threadCpuNanos() - cpu0_ : 0;
    tChunkCpu += cpu;
    if (!owner_) return;
    owner_->chunkCpuNs.fetch_add(cpu, std::memory_order_relaxed);
    owner_->chunks.fetch_add(1, std::memory_order_relaxed);
    if (wall0_ != 0) {
        TraceRecorder::instance().record(
            {owner_->label, "chunk", threadSlot(), wall0_, wallNanos(), items_});
    }
}

}  // namespace fg::jobs
