// Scheduler overhead per pass instance: a repeat block of N trivial passes
// (each reads the carried counter and writes the next one), so nearly all the
// time is the engine's own — unrolling, validation, the task graph, buffer
// hand-over and per-pass timing. Reported as seconds per instance
// (`per_instance`), for planning alone and for planning plus running.
//   build/tools/bench/fluxgraph_bench --benchmark_filter=Scheduler
#include "engine/core/scheduler.h"
#include "engine/scene/scene.h"

#include <benchmark/benchmark.h>

#include <memory>
#include <string>

namespace fg {
namespace {

struct Tally {
    std::int64_t value = 0;
    std::size_t bytes() const { return sizeof(value); }
};

}  // namespace

template <>
struct BufferTypeName<Tally> {
    static constexpr const char* value = "Tally";
};

namespace {

class IncrementPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const std::int64_t previous = ctx.hasInput("previous") ? ctx.input<Tally>("previous").value : 0;
        ctx.createOutput<Tally>("tally").value = previous + 1;
    }
};

std::vector<PassRegistration> incrementRegistry() {
    PassSpec spec;
    spec.name = "increment";
    SlotSpec previous{"previous", "Tally", "the count so far"};
    previous.optional = true;
    spec.inputs = {previous};
    spec.outputs = {{"tally", "Tally", "the count plus one"}};
    return {{spec, [] { return std::make_unique<IncrementPass>(); }}};
}

Pipeline blockOf(int count) {
    Pipeline pipeline;
    pipeline.name = "bench";
    RepeatBlock block;
    block.name = "loop";
    block.count = count;
    block.carry = {{"tally", "tally"}};
    block.nodes = {{"step", "increment", {{"previous", "tally"}}, {}, 0}};
    pipeline.blocks = {block};
    pipeline.results = {"tally"};
    return pipeline;
}

void BM_SchedulerPlan(benchmark::State& state) {
    const auto registry = incrementRegistry();
    const Pipeline pipeline = blockOf(static_cast<int>(state.range(0)));
    for (auto _ : state) benchmark::DoNotOptimize(ExecutionPlan::build(pipeline, {}, "bench", registry));
    state.counters["per_instance"] = benchmark::Counter(
        static_cast<double>(state.range(0)), benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_SchedulerPlan)->Arg(1000)->Unit(benchmark::kMillisecond);

void BM_SchedulerPlanAndRun(benchmark::State& state) {
    const auto registry = incrementRegistry();
    const Pipeline pipeline = blockOf(static_cast<int>(state.range(0)));
    const Scene scene;
    for (auto _ : state) {
        const ExecutionPlan plan = ExecutionPlan::build(pipeline, {}, "bench", registry);
        const RunResult run = execute(plan, scene, nullptr, RunOptions{});
        if (static_cast<const Tally*>(run.results.at("tally").data.get())->value != state.range(0))
            state.SkipWithError("wrong count");
    }
    state.counters["per_instance"] = benchmark::Counter(
        static_cast<double>(state.range(0)), benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_SchedulerPlanAndRun)->Arg(1000)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace fg
