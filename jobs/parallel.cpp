#include "jobs/parallel.h"

#include <tbb/flow_graph.h>
#include <tbb/global_control.h>
#include <tbb/info.h>

#include <atomic>
#include <exception>
#include <mutex>
#include <thread>

#if defined(__SSE__) || defined(_M_X64)
#include <xmmintrin.h>
#endif

namespace fg::jobs {

void useDeterministicFloatMode() {
#if defined(__SSE__) || defined(_M_X64)
    // Bit 15 flushes subnormal results to zero (FTZ), bit 6 reads subnormal
    // operands as zero (DAZ); rounding and exception masks are left alone.
    constexpr unsigned kFlushAndDenormalsAreZero = (1u << 15) | (1u << 6);
    const unsigned mode = _mm_getcsr();
    if ((mode & kFlushAndDenormalsAreZero) != kFlushAndDenormalsAreZero) _mm_setcsr(mode | kFlushAndDenormalsAreZero);
#endif
}

int maxThreads() {
    return static_cast<int>(
        tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
}

int hardwareThreads() { return static_cast<int>(tbb::info::default_concurrency()); }

struct ThreadLimit::Impl {
    std::unique_ptr<tbb::global_control> control;
};

ThreadLimit::ThreadLimit(int threads) : impl_(std::make_unique<Impl>()) {
    if (threads > 0) {
        impl_->control = std::make_unique<tbb::global_control>(
            tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
    }
}

ThreadLimit::~ThreadLimit() = default;

struct TaskGraph::Impl {
    tbb::flow::graph graph;
    std::vector<std::unique_ptr<tbb::flow::continue_node<tbb::flow::continue_msg>>> nodes;
    std::vector<bool> hasPredecessor;
    std::mutex errorMutex;
    std::exception_ptr firstError;
    std::atomic<bool> failed{false};
};

TaskGraph::TaskGraph() : impl_(std::make_unique<Impl>()) {}
TaskGraph::~TaskGraph() = default;

int TaskGraph::addTask(std::function<void()> task) {
    Impl* impl = impl_.get();
    auto body = [impl, task = std::move(task)](const tbb::flow::continue_msg&) {
        if (impl->failed.load()) return;
        useDeterministicFloatMode();
        try {
            task();
        } catch (...) {
            std::lock_guard lock(impl->errorMutex);
            if (!impl->firstError) impl->firstError = std::current_exception();
            impl->failed.store(true);
        }
    };
    impl_->nodes.push_back(
        std::make_unique<tbb::flow::continue_node<tbb::flow::continue_msg>>(impl_->graph, body));
    impl_->hasPredecessor.push_back(false);
    return static_cast<int>(impl_->nodes.size()) - 1;
}

void TaskGraph::addEdge(int from, int to) {
    tbb::flow::make_edge(*impl_->nodes.at(from), *impl_->nodes.at(to));
    impl_->hasPredecessor.at(to) = true;
}

void TaskGraph::run() {
    for (std::size_t i = 0; i < impl_->nodes.size(); ++i)
        if (!impl_->hasPredecessor[i]) impl_->nodes[i]->try_put(tbb::flow::continue_msg());
    impl_->graph.wait_for_all();
    if (impl_->firstError) std::rethrow_exception(impl_->firstError);
}

}  // namespace fg::jobs
