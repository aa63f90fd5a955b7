// kd-tree build time over one million points and query throughput (k = 50
// nearest neighbours, and a fixed-radius range holding about 50 points), per
// leaf size and thread count. The point set is uniform in the unit cube or
// "surface-like": points on the six faces of the cube, as photons land.
//
//   build/tools/bench/fluxgraph_bench --benchmark_filter=KdTree
#include "engine/accel/kdtree.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace {

using namespace fg;

constexpr std::size_t kPointCount = 1000000;
constexpr std::size_t kQueryCount = 1 << 16;
constexpr std::size_t kNeighbours = 50;

Vec3 uniformPoint(jobs::Rng& rng) {
    const float x = rng.uniform();
    const float y = rng.uniform();
    const float z = rng.uniform();
    return {x, y, z};
}

std::vector<Vec3> makePoints(int kind, std::size_t n, std::uint64_t seed) {
    jobs::Rng rng(seed, jobs::streamKey("bench-kdtree"), 0);
    std::vector<Vec3> points(n);
    for (Vec3& p : points) {
        p = uniformPoint(rng);
        if (kind == 1) {
            const std::uint32_t face = rng.uniformIndex(6);
            p[static_cast<int>(face % 3)] = face < 3 ? 0.0f : 1.0f;
        }
    }
    return points;
}

const std::vector<Vec3>& points(int kind) {
    static const std::vector<Vec3> sets[2] = {makePoints(0, kPointCount, 1), makePoints(1, kPointCount, 1)};
    return sets[kind];
}

// Queries at stored points, the way a gather looks up around a hit point.
const std::vector<Vec3>& queries(int kind) {
    static const std::vector<Vec3> sets[2] = {makePoints(0, kQueryCount, 2), makePoints(1, kQueryCount, 2)};
    return sets[kind];
}

const char* kindName(int kind) { return kind == 0 ? "uniform" : "surface"; }

// Args: leaf size, threads, point-set kind.
void BM_KdTreeBuild(benchmark::State& state) {
    const auto leaf = static_cast<std::uint32_t>(state.range(0));
    const jobs::ThreadLimit limit(static_cast<int>(state.range(1)));
    const int kind = static_cast<int>(state.range(2));
    const std::vector<Vec3>& pts = points(kind);
    KdTree tree;
    for (auto _ : state) {
        tree.build(pts, {.maxLeafSize = leaf});
        benchmark::DoNotOptimize(tree.permutation().data());
    }
    state.counters["points_per_s"] = benchmark::Counter(
        static_cast<double>(pts.size()) * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
    state.counters["tree_MiB"] = static_cast<double>(tree.bytes()) / (1024.0 * 1024.0);
    state.SetLabel(kindName(kind));
}

// Args: leaf size, threads, point-set kind.
void BM_KdTreeKnn(benchmark::State& state) {
    const auto leaf = static_cast<std::uint32_t>(state.range(0));
    const int kind = static_cast<int>(state.range(2));
    const KdTree tree(points(kind), {.maxLeafSize = leaf});
    const std::vector<Vec3>& centers = queries(kind);
    const jobs::ThreadLimit limit(static_cast<int>(state.range(1)));
    std::vector<std::uint32_t> indices(centers.size() * kNeighbours);
    std::vector<float> dist2(centers.size() * kNeighbours);
    for (auto _ : state) {
        jobs::parallelForChunks(centers.size(), 256, [&](jobs::IndexRange r) {
            for (std::size_t q = r.begin; q != r.end; ++q) {
                tree.nearest(centers[q], kNeighbours, std::numeric_limits<float>::infinity(),
                             std::span(indices).subspan(q * kNeighbours, kNeighbours),
                             std::span(dist2).subspan(q * kNeighbours, kNeighbours));
            }
        });
        benchmark::DoNotOptimize(dist2.data());
    }
    state.counters["queries_per_s"] = benchmark::Counter(
        static_cast<double>(centers.size()) * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
    state.SetLabel(kindName(kind));
}

// Args: leaf size, threads, point-set kind. The radius holds about 50 points of
// the uniform set; on the surface set it holds a comparable number on a face.
void BM_KdTreeRadius(benchmark::State& state) {
    const auto leaf = static_cast<std::uint32_t>(state.range(0));
    const int kind = static_cast<int>(state.range(2));
    const KdTree tree(points(kind), {.maxLeafSize = leaf});
    const std::vector<Vec3>& centers = queries(kind);
    const float radius = kind == 0 ? std::cbrt(3.0f * kNeighbours / (4.0f * kPi * kPointCount))
                                   : std::sqrt(6.0f * kNeighbours / (kPi * kPointCount));
    const jobs::ThreadLimit limit(static_cast<int>(state.range(1)));
    std::vector<float> sums(centers.size());
    std::size_t visited = 0;
    for (auto _ : state) {
        jobs::parallelForChunks(centers.size(), 256, [&](jobs::IndexRange r) {
            for (std::size_t q = r.begin; q != r.end; ++q) {
                float sum = 0.0f;
                tree.forEachInRadius(centers[q], radius, [&](std::uint32_t, float d2) { sum += d2 + 1.0f; });
                sums[q] = sum;
            }
        });
        benchmark::DoNotOptimize(sums.data());
    }
    for (std::size_t q = 0; q < centers.size(); ++q) visited += static_cast<std::size_t>(sums[q] > 0.0f);
    state.counters["queries_per_s"] = benchmark::Counter(
        static_cast<double>(centers.size()) * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
    state.counters["nonempty_fraction"] = static_cast<double>(visited) / static_cast<double>(centers.size());
    state.SetLabel(kindName(kind));
}

void kdtreeArgs(benchmark::internal::Benchmark* b) {
    const int hw = jobs::hardwareThreads();
    for (int kind = 0; kind < 2; ++kind)
        for (int leaf : {1, 4, 8, 16})
            for (int threads : {1, hw}) {
                b->Args({leaf, threads, kind});
                if (hw == 1) break;
            }
}

BENCHMARK(BM_KdTreeBuild)->Apply(kdtreeArgs)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(0.5);
BENCHMARK(BM_KdTreeKnn)->Apply(kdtreeArgs)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(0.5);
BENCHMARK(BM_KdTreeRadius)->Apply(kdtreeArgs)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(0.5);

}  // namespace
