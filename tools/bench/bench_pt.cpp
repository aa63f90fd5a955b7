// Throughput of the path tracer against the raw ray-query throughput it is
// built on, on the Cornell box, at 1 and 2 (or more) threads. Run through
// tools/bench_report.py, which prints the ratios and parallel efficiencies.
//
//   build/tools/bench/fluxgraph_bench --benchmark_filter=. [--benchmark_format=json]
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "engine/scene/scene_loader.h"
#include "engine/core/scheduler.h"
#include "passes/passes.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <benchmark/benchmark.h>

#include <memory>
#include <string>

namespace {

using namespace fg;

const Scene& cornellBox() {
    static const Scene scene = loadScene(std::string(FLUXGRAPH_SOURCE_DIR) + "/data/cornell-box/cornell-box.toml");
    return scene;
}

const RayQuery& cornellRays() {
    static const RayQuery rays(cornellBox());
    return rays;
}

// A fixed mix of camera rays and diffuse bounce rays from the first hits, the
// population a path tracer actually traces.
const std::vector<Ray>& rayPopulation() {
    static const std::vector<Ray> rays = [] {
        const Scene& scene = cornellBox();
        const RayQuery& query = cornellRays();
        Camera cam = scene.camera;
        cam.width = cam.height = 512;
        std::vector<Ray> out;
        out.reserve(1 << 20);
        jobs::Rng rng(1, jobs::streamKey("bench"), 0);
        while (out.size() < (1u << 20)) {
            const Ray primary = cam.generateRay(Vec2(rng.uniform() * 512.0f, rng.uniform() * 512.0f));
            out.push_back(primary);
            const Hit hit = query.intersect(primary);
            if (!hit.valid()) continue;
            const SurfacePoint sp = query.surface(primary, hit);
            const Vec3 n = glm::dot(sp.ng, primary.direction) < 0 ? sp.ng : -sp.ng;
            const Vec3 dir = Frame(n).toWorld(sampleCosineHemisphere(rng.uniform2()));
            out.push_back(Ray{offsetRayOrigin(sp.p, n, dir), dir, kInfinity});
        }
        out.resize(1u << 20);
        return out;
    }();
    return rays;
}

void BM_EmbreeClosestHit(benchmark::State& state) {
    const jobs::ThreadLimit limit(static_cast<int>(state.range(0)));
    const RayQuery& query = cornellRays();
    const std::vector<Ray>& rays = rayPopulation();
    std::vector<Hit> hits(rays.size());
    for (auto _ : state) {
        jobs::parallelForChunks(rays.size(), 256, [&](jobs::IndexRange r) {
            query.intersect(std::span<const Ray>(rays).subspan(r.begin, r.size()),
                            std::span<Hit>(hits).subspan(r.begin, r.size()));
        });
        benchmark::DoNotOptimize(hits.data());
    }
    state.counters["rays_per_s"] =
        benchmark::Counter(static_cast<double>(rays.size()) * static_cast<double>(state.iterations()),
                           benchmark::Counter::kIsRate);
}

void BM_PathTracer(benchmark::State& state) {
    const int threads = static_cast<int>(state.range(0));
    const std::string schedule = state.range(1) == 0 ? "wavefront" : "tile";
    const jobs::ThreadLimit limit(threads);
    const Scene& scene = cornellBox();
    const RayQuery& query = cornellRays();
    JobParams params;
    params.values["pt"]["spp"] = {std::int64_t{16}, "bench"};
    params.values["pt"]["schedule"] = {schedule, "bench"};
    const ExecutionPlan plan = ExecutionPlan::build(*findPipeline("pt"), params, "bench", passRegistry());
    RunOptions options;
    options.film.width = options.film.height = 128;
    double segments = 0.0, samples = 0.0, wall = 0.0, cpu = 0.0;
    for (auto _ : state) {
        const RunResult result = execute(plan, scene, query, options);
        const PassStats& pt = result.stats.front();
        segments += static_cast<double>(pt.counters.at("path_segments"));
        samples += static_cast<double>(pt.items);
        wall += pt.wallSeconds;
        cpu += pt.cpuSeconds;
    }
    state.counters["path_segments_per_s"] = benchmark::Counter(segments, benchmark::Counter::kIsRate);
    state.counters["samples_per_s"] = benchmark::Counter(samples, benchmark::Counter::kIsRate);
    state.counters["pass_wall_s"] = wall / static_cast<double>(state.iterations());
    state.counters["pass_cpu_s"] = cpu / static_cast<double>(state.iterations());
    state.SetLabel(schedule);
}

void threadArgs(benchmark::internal::Benchmark* b) {
    const int hw = jobs::hardwareThreads();
    for (int t = 1; t <= hw; t *= 2) b->Arg(t);
    if ((hw & (hw - 1)) != 0) b->Arg(hw);
}

void ptArgs(benchmark::internal::Benchmark* b) {
    const int hw = jobs::hardwareThreads();
    for (int schedule = 0; schedule < 2; ++schedule) {
        for (int t = 1; t <= hw; t *= 2) b->Args({t, schedule});
        if ((hw & (hw - 1)) != 0) b->Args({hw, schedule});
    }
}

BENCHMARK(BM_EmbreeClosestHit)->Apply(threadArgs)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
BENCHMARK(BM_PathTracer)->Apply(ptArgs)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

}  // namespace

BENCHMARK_MAIN();
