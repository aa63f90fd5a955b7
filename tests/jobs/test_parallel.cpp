#include "jobs/parallel.h"
#include "jobs/random.h"
#include "jobs/work_context.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <ctime>
#include <mutex>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#if defined(__SSE__)
#include <xmmintrin.h>
#endif

namespace fg::jobs {
namespace {

// Work the optimiser cannot remove, so that chunks take measurable CPU time.
double busyWork(std::size_t seed, int iterations) {
    double x = static_cast<double>(seed % 7) + 0.5;
    for (int k = 0; k < iterations; ++k) x = std::sqrt(x * x + 1.0) - 0.999 * x;
    return x;
}

std::int64_t processCpuNanos() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return static_cast<std::int64_t>(ts.tv_sec) * 1000000000ll + ts.tv_nsec;
}

TEST(ParallelFor, VisitsEveryIndexExactlyOnce) {
    for (std::size_t n : {0u, 1u, 2u, 7u, 1000u, 1023u, 1024u, 1025u, 100000u}) {
        for (std::size_t grain : {0u, 1u, 3u, 64u, 1000u, 5000u}) {
            std::vector<std::atomic<int>> visits(n);
            parallelFor(n, grain, [&](std::size_t i) { visits[i].fetch_add(1, std::memory_order_relaxed); });
            std::size_t wrong = 0;
            for (const auto& v : visits) wrong += v.load() != 1;
            EXPECT_EQ(wrong, 0u) << "n=" << n << " grain=" << grain;
        }
    }
}

TEST(ParallelForChunks, ChunkBoundariesDependOnlyOnSizeAndGrain) {
    const std::size_t n = 10007;
    for (std::size_t grain : {1u, 16u, 100u, 20000u}) {
        std::mutex mutex;
        std::vector<IndexRange> chunks;
        parallelForChunks(n, grain, [&](IndexRange r) {
            std::lock_guard lock(mutex);
            chunks.push_back(r);
        });
        std::sort(chunks.begin(), chunks.end(), [](IndexRange a, IndexRange b) { return a.begin < b.begin; });
        ASSERT_EQ(chunks.size(), (n + grain - 1) / grain) << "grain=" << grain;
        std::size_t expectedBegin = 0;
        for (const IndexRange& r : chunks) {
            EXPECT_EQ(r.begin, expectedBegin);
            EXPECT_EQ(r.size(), std::min(grain, n - r.begin));
            expectedBegin = r.end;
        }
        EXPECT_EQ(expectedBegin, n);
    }
}

// Values spanning many orders of magnitude and both signs, so that summing them
// in a different association gives a different float.
std::vector<float> variedValues(std::size_t n) {
    std::vector<float> values(n);
    for (std::size_t i = 0; i < n; ++i) {
        Rng rng(7, 0, i);
        const float mantissa = rng.uniform() - 0.4f;
        const int exponent = static_cast<int>(rng.uniformIndex(40)) - 20;
        values[i] = std::ldexp(mantissa, exponent);
    }
    return values;
}

float blockedSum(const std::vector<float>& values, std::size_t blocks) {
    return deterministicReduce<float>(
        values.size(), blocks, [] { return 0.0f; },
        [&](float& acc, IndexRange r) {
            for (std::size_t i = r.begin; i != r.end; ++i) acc += values[i];
        },
        [](float& total, const float& part) { total += part; });
}

#if defined(__SSE__)
// A product whose exact value is subnormal: 0 under flush-to-zero.
float subnormalProduct() {
    volatile float small = 1e-30f, factor = 1e-10f;
    return small * factor;
}

TEST(FloatMode, ChunksAndTasksFlushSubnormalsWhateverTheThreadHadSet) {
    // The calling thread (which also runs chunks) starts with IEEE gradual underflow.
    const unsigned saved = _mm_getcsr();
    _mm_setcsr(saved & ~((1u << 15) | (1u << 6)));
    ASSERT_NE(subnormalProduct(), 0.0f);
    std::vector<float> products(64, -1.0f);
    {
        const jobs::ThreadLimit limit(2);
        jobs::parallelFor(products.size(), 1, [&](std::size_t i) { products[i] = subnormalProduct(); });
    }
    for (float p : products) EXPECT_EQ(p, 0.0f);
    float inTask = -1.0f;
    _mm_setcsr(saved & ~((1u << 15) | (1u << 6)));
    jobs::TaskGraph graph;
    graph.addTask([&] { inTask = subnormalProduct(); });
    graph.run();
    EXPECT_EQ(inTask, 0.0f);
    _mm_setcsr(saved);
}
#endif

TEST(DeterministicReduce, FloatSumIsBitIdenticalForAnyThreadCount) {
    const std::vector<float> values = variedValues(1 << 18);
    std::vector<std::uint32_t> bits;
    for (int threads : {1, 2, 4}) {
        ThreadLimit limit(threads);
        for (int repeat = 0; repeat < 3; ++repeat) bits.push_back(std::bit_cast<std::uint32_t>(blockedSum(values, 97)));
    }
    for (std::size_t k = 1; k < bits.size(); ++k) EXPECT_EQ(bits[k], bits[0]) << "run " << k;

    // The data are sensitive to summation order: another blocking or a plain
    // left-to-right sum gives a different float, so equality above means something.
    float serial = 0.0f;
    for (float v : values) serial += v;
    EXPECT_NE(std::bit_cast<std::uint32_t>(blockedSum(values, 96)), bits[0]);
    EXPECT_NE(std::bit_cast<std::uint32_t>(serial), bits[0]);
}

TEST(DeterministicReduce, SumsIntegersExactlyForAnyBlocking) {
    for (std::size_t n : {0u, 1u, 5u, 1000u, 12345u}) {
        for (std::size_t blocks : {0u, 1u, 3u, 64u, 100000u}) {
            const auto sum = deterministicReduce<std::uint64_t>(
                n, blocks, [] { return std::uint64_t{0}; },
                [](std::uint64_t& acc, IndexRange r) {
                    for (std::size_t i = r.begin; i != r.end; ++i) acc += i + 1;
                },
                [](std::uint64_t& total, const std::uint64_t& part) { total += part; });
            EXPECT_EQ(sum, static_cast<std::uint64_t>(n) * (n + 1) / 2) << "n=" << n << " blocks=" << blocks;
        }
    }
}

TEST(ThreadLimit, CapsAndRestoresTheWorkerCount) {
    const int before = maxThreads();
    EXPECT_GE(hardwareThreads(), 1);
    {
        ThreadLimit limit(1);
        EXPECT_EQ(maxThreads(), 1);
        std::atomic<int> sum{0};
        parallelFor(100, 1, [&](std::size_t i) { sum += static_cast<int>(i); });
        EXPECT_EQ(sum.load(), 4950);
    }
    EXPECT_EQ(maxThreads(), before);
    {
        ThreadLimit unlimited(0);
        EXPECT_EQ(maxThreads(), before);
    }
}

TEST(WorkContext, ChunksBookCpuTimeToTheContextOfTheStartingThread) {
    EXPECT_EQ(currentContext(), nullptr);
    WorkContext work;
    work.label = "busy";
    std::atomic<int> seenOwner{0};
    std::atomic<double> sink{0.0};
    const std::int64_t cpu0 = processCpuNanos();
    {
        ScopedContext scope(&work);
        EXPECT_EQ(currentContext(), &work);
        parallelFor(64, 1, [&](std::size_t i) {
            // Worker threads see the owner too, so nested loops book to the same pass.
            if (currentContext() == &work) seenOwner.fetch_add(1);
            sink.store(busyWork(i, 20000));
        });
    }
    const std::int64_t processCpu = processCpuNanos() - cpu0;
    EXPECT_EQ(currentContext(), nullptr);
    EXPECT_EQ(seenOwner.load(), 64);
    EXPECT_EQ(work.chunks.load(), 64);
    EXPECT_GT(work.chunkCpuNs.load(), 0);
    EXPECT_LE(work.chunkCpuNs.load(), processCpu + 1000000);

    // Outside the scope nothing is booked to it any more.
    const std::int64_t booked = work.chunkCpuNs.load();
    parallelFor(16, 1, [&](std::size_t i) { sink.store(busyWork(i, 20000)); });
    EXPECT_EQ(work.chunkCpuNs.load(), booked);
    EXPECT_EQ(work.chunks.load(), 64);
}

TEST(WorkContext, NestedLoopsAreNotCountedTwice) {
    WorkContext work;
    std::atomic<double> sink{0.0};
    const std::int64_t cpu0 = processCpuNanos();
    {
        ScopedContext scope(&work);
        parallelFor(4, 1, [&](std::size_t i) {
            parallelFor(8, 1, [&](std::size_t j) { sink.store(busyWork(i * 8 + j, 40000)); });
        });
    }
    const std::int64_t processCpu = processCpuNanos() - cpu0;
    EXPECT_EQ(work.chunks.load(), 4 + 4 * 8);
    EXPECT_GT(work.chunkCpuNs.load(), 0);
    // Counting inner chunks inside their outer chunk again would roughly double this.
    EXPECT_LE(work.chunkCpuNs.load(), processCpu + 1000000);
}

TEST(TaskGraph, RunsEveryTaskAfterItsPredecessors) {
    for (std::uint64_t trial = 0; trial < 20; ++trial) {
        Rng rng(3, trial, 0);
        const int count = 40;
        TaskGraph graph;
        std::atomic<int> clock{0};
        std::vector<int> finishedAt(count, -1), startedAt(count, -1);
        std::vector<std::atomic<int>> runs(count);
        for (int t = 0; t < count; ++t) {
            EXPECT_EQ(graph.addTask([&, t] {
                startedAt[static_cast<std::size_t>(t)] = clock.fetch_add(1);
                runs[static_cast<std::size_t>(t)].fetch_add(1);
                finishedAt[static_cast<std::size_t>(t)] = clock.fetch_add(1);
            }),
                      t);
        }
        std::vector<std::pair<int, int>> edges;
        for (int from = 0; from < count; ++from)
            for (int to = from + 1; to < count; ++to)
                if (rng.uniform() < 0.08f) edges.emplace_back(from, to);
        for (const auto& [from, to] : edges) graph.addEdge(from, to);
        graph.run();
        for (const auto& r : runs) EXPECT_EQ(r.load(), 1);
        for (const auto& [from, to] : edges) {
            EXPECT_LT(finishedAt[static_cast<std::size_t>(from)], startedAt[static_cast<std::size_t>(to)])
                << "edge " << from << " -> " << to << " in trial " << trial;
        }
    }
}

TEST(TaskGraph, IndependentTasksAllRunAndMayUseParallelLoops) {
    TaskGraph graph;
    const int count = 32;
    std::vector<std::int64_t> sums(count, 0);
    for (int t = 0; t < count; ++t) {
        graph.addTask([&, t] {
            std::atomic<std::int64_t> sum{0};
            parallelFor(1000, 10, [&](std::size_t i) { sum += static_cast<std::int64_t>(i) * (t + 1); });
            sums[static_cast<std::size_t>(t)] = sum.load();
        });
    }
    graph.run();
    for (int t = 0; t < count; ++t) EXPECT_EQ(sums[static_cast<std::size_t>(t)], 499500 * (t + 1)) << "task " << t;
}

TEST(TaskGraph, ExceptionIsRethrownAndSuccessorsAreSkipped) {
    TaskGraph graph;
    std::atomic<bool> successorRan{false}, laterRan{false}, independentRan{false};
    const int source = graph.addTask([] {});
    const int failing = graph.addTask([] { throw std::runtime_error("task exploded"); });
    const int successor = graph.addTask([&] { successorRan = true; });
    const int later = graph.addTask([&] { laterRan = true; });
    graph.addEdge(source, failing);
    graph.addEdge(failing, successor);
    graph.addEdge(successor, later);
    graph.addTask([&] { independentRan = true; });
    try {
        graph.run();
        FAIL() << "run() returned although a task threw";
    } catch (const std::runtime_error& e) {
        EXPECT_STREQ(e.what(), "task exploded");
    }
    EXPECT_FALSE(successorRan.load());
    EXPECT_FALSE(laterRan.load());
    (void)independentRan;  // may or may not have started before the failure
}

TEST(TaskGraph, EmptyGraphRuns) {
    TaskGraph graph;
    EXPECT_NO_THROW(graph.run());
}

}  // namespace
}  // namespace fg::jobs
