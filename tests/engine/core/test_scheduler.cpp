#include "engine/core/scheduler.h"

#include "tests/support/pass_helpers.h"

#include "engine/core/error.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <functional>
#include <memory>
#include <mutex>
#include <numeric>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace fg {
namespace {

// A buffer of numbers that reports its own destruction, so tests can see when
// the scheduler frees it.
struct NumberBuffer {
    std::vector<double> values;
    std::shared_ptr<std::atomic<bool>> destroyed;
    NumberBuffer(std::vector<double> v, std::shared_ptr<std::atomic<bool>> flag)
        : values(std::move(v)), destroyed(std::move(flag)) {}
    ~NumberBuffer() {
        if (destroyed) destroyed->store(true);
    }
    NumberBuffer(const NumberBuffer&) = delete;
    NumberBuffer& operator=(const NumberBuffer&) = delete;
    std::size_t bytes() const { return values.capacity() * sizeof(double); }
};

// A second buffer type, for type mismatches.
struct LabelBuffer {
    std::string text;
    std::size_t bytes() const { return text.size(); }
};

}  // namespace

template <>
struct BufferTypeName<NumberBuffer> {
    static constexpr const char* value = "Numbers";
};
template <>
struct BufferTypeName<LabelBuffer> {
    static constexpr const char* value = "Label";
};

namespace {

using test::PassBody;

SlotSpec numbers(const std::string& name) { return {name, "Numbers", ""}; }

PassRegistration makePass(const std::string& name, std::vector<SlotSpec> inputs, std::vector<SlotSpec> outputs,
                          PassBody body, std::vector<ParamSpec> params = {}) {
    PassSpec spec;
    spec.name = name;
    spec.doc = "test pass " + name;
    spec.inputs = std::move(inputs);
    spec.outputs = std::move(outputs);
    spec.params = std::move(params);
    return test::lambdaPass(std::move(spec), std::move(body));
}

PipelineNode node(const std::string& instance, const std::string& pass, int line,
                  std::map<std::string, std::string> inputs = {}, std::map<std::string, std::string> outputs = {}) {
    PipelineNode n;
    n.instance = instance;
    n.pass = pass;
    n.sourceLine = line;
    n.inputBindings = std::move(inputs);
    n.outputBindings = std::move(outputs);
    return n;
}

Pipeline pipeline(std::vector<PipelineNode> nodes, std::vector<std::string> results) {
    Pipeline p;
    p.name = "test";
    p.nodes = std::move(nodes);
    p.results = std::move(results);
    return p;
}

const std::vector<double>& valuesOf(const PassContext& ctx, const std::string& slot) {
    return ctx.input<NumberBuffer>(slot).values;
}

// The registry the validation tests build against.
std::vector<PassRegistration> validationRegistry() {
    const PassBody nothing = [](PassContext&) {};
    std::vector<ParamSpec> sourceParams = {
        {"count", ParamType::Int, std::int64_t{4}, 1, 100, {}, "how many numbers"},
        {"scale", ParamType::Float, 1.0, 0.0, 10.0, {}, "factor"},
        {"mode", ParamType::String, std::string("fast"), -1e300, 1e300, {"fast", "slow"}, "how"},
        {"verbose", ParamType::Bool, false, -1e300, 1e300, {}, "chatty"},
    };
    return {
        makePass("source", {}, {numbers("a")}, nothing, sourceParams),
        makePass("filter", {numbers("a")}, {numbers("b")}, nothing),
        makePass("back", {numbers("b")}, {numbers("a")}, nothing),
        makePass("labeller", {}, {{"a", "Label", ""}}, nothing),
        makePass("sink", {numbers("b")}, {numbers("image")}, nothing),
        makePass("feedback", {numbers("a")}, {numbers("a")}, nothing),
    };
}

// Builds and returns the InputError's message; fails the test if nothing is thrown.
std::string buildError(const Pipeline& p, const JobParams& params = {}) {
    const auto registry = validationRegistry();
    try {
        ExecutionPlan::build(p, params, "job.toml", registry);
    } catch (const InputError& e) {
        return e.what();
    }
    ADD_FAILURE() << "ExecutionPlan::build accepted an invalid pipeline";
    return {};
}

JobParams oneSetting(const std::string& instance, const std::string& key, ParamValue value, int line) {
    JobParams params;
    params.values[instance][key] = {std::move(value), "job.toml:" + std::to_string(line)};
    params.tableSource[instance] = "job.toml:" + std::to_string(line - 1);
    return params;
}

Pipeline sourceFilterSink() {
    return pipeline({node("source", "source", 3), node("filter", "filter", 6), node("sink", "sink", 9)}, {"image"});
}

::testing::AssertionResult Contains(const std::string& text, const std::string& part) {
    if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << "'" << text << "' does not contain '" << part << "'";
}
::testing::AssertionResult BeginsWith(const std::string& text, const std::string& prefix) {
    if (text.rfind(prefix, 0) == 0) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << "'" << text << "' does not begin with '" << prefix << "'";
}

TEST(ExecutionPlan, AcceptsAValidPipelineAndResolvesParameters) {
    JobParams params = oneSetting("source", "count", std::int64_t{7}, 12);
    params.values["source"]["scale"] = {std::int64_t{2}, "job.toml:13"};  // an integer where a float is taken
    params.values["source"]["mode"] = {std::string("slow"), "job.toml:14"};
    const auto registry = validationRegistry();
    const ExecutionPlan plan = ExecutionPlan::build(sourceFilterSink(), params, "job.toml", registry);
    ASSERT_EQ(plan.passes().size(), 3u);
    const PassParams& resolved = plan.passes()[0].params;
    EXPECT_EQ(resolved.getInt("count"), 7);
    EXPECT_EQ(resolved.getFloat("scale"), 2.0);
    EXPECT_EQ(resolved.getString("mode"), "slow");
    EXPECT_FALSE(resolved.getBool("verbose"));  // default
    EXPECT_EQ(plan.passes()[1].dependencies, std::vector<int>{0});
    EXPECT_EQ(plan.passes()[2].dependencies, std::vector<int>{1});
    EXPECT_EQ(plan.topologicalOrder(), (std::vector<int>{0, 1, 2}));
    for (const auto& p : plan.passes()) EXPECT_FALSE(p.culled) << p.node.instance;
}

TEST(ExecutionPlan, OrdersPassesByDependencyNotByListing) {
    const auto registry = validationRegistry();
    const ExecutionPlan plan = ExecutionPlan::build(
        pipeline({node("sink", "sink", 1), node("filter", "filter", 2), node("source", "source", 3)}, {"image"}), {},
        "job.toml", registry);
    EXPECT_EQ(plan.topologicalOrder(), (std::vector<int>{2, 1, 0}));
}

TEST(ExecutionPlanErrors, MissingInputNamesTheBufferAndThePass) {
    const std::string message = buildError(pipeline({node("filter", "filter", 6)}, {"b"}));
    EXPECT_TRUE(BeginsWith(message, "job.toml:6: "));
    EXPECT_TRUE(Contains(message, "'filter'"));
    EXPECT_TRUE(Contains(message, "buffer 'a'"));
    EXPECT_TRUE(Contains(message, "no pass produces"));
}

TEST(ExecutionPlanErrors, TypeMismatchNamesBothTypes) {
    const std::string message =
        buildError(pipeline({node("labeller", "labeller", 2), node("filter", "filter", 5)}, {"b"}));
    EXPECT_TRUE(BeginsWith(message, "job.toml:5: "));
    EXPECT_TRUE(Contains(message, "expects Numbers"));
    EXPECT_TRUE(Contains(message, "is Label"));
    EXPECT_TRUE(Contains(message, "'labeller'"));
}

TEST(ExecutionPlanErrors, CycleNamesThePassesOnIt) {
    const std::string message = buildError(
        pipeline({node("filter", "filter", 2), node("back", "back", 5), node("sink", "sink", 8)}, {"image"}));
    EXPECT_TRUE(BeginsWith(message, "job.toml: "));
    EXPECT_TRUE(Contains(message, "cycle"));
    EXPECT_TRUE(Contains(message, "filter"));
    EXPECT_TRUE(Contains(message, "back"));
    EXPECT_FALSE(Contains(message, "sink"));  // downstream of the cycle, not on it
}

TEST(ExecutionPlanErrors, PassReadingItsOwnOutputIsACycle) {
    const std::string message = buildError(
        pipeline({node("loop", "feedback", 2, {{"a", "x"}}, {{"a", "x"}}), node("reader", "filter", 4, {{"a", "x"}})},
                 {"b"}));
    EXPECT_TRUE(Contains(message, "cycle through passes: loop"));
    EXPECT_FALSE(Contains(message, "reader"));
}

TEST(ExecutionPlanErrors, UnknownPassListsTheRegisteredOnes) {
    const std::string message = buildError(pipeline({node("x", "no_such_pass", 4)}, {"image"}));
    EXPECT_TRUE(BeginsWith(message, "job.toml:4: "));
    EXPECT_TRUE(Contains(message, "unknown pass 'no_such_pass'"));
    EXPECT_TRUE(Contains(message, "source"));
}

TEST(ExecutionPlanErrors, UnknownParameterNamesItsSource) {
    const std::string message = buildError(sourceFilterSink(), oneSetting("source", "cuont", std::int64_t{3}, 17));
    EXPECT_TRUE(BeginsWith(message, "job.toml:17: "));
    EXPECT_TRUE(Contains(message, "unknown parameter 'cuont'"));
    EXPECT_TRUE(Contains(message, "count"));  // the parameters it does take
}

TEST(ExecutionPlanErrors, IntOutsideItsRange) {
    for (std::int64_t bad : {std::int64_t{0}, std::int64_t{101}, std::int64_t{-5}}) {
        const std::string message = buildError(sourceFilterSink(), oneSetting("source", "count", bad, 21));
        EXPECT_TRUE(BeginsWith(message, "job.toml:21: "));
        EXPECT_TRUE(Contains(message, "source.count"));
        EXPECT_TRUE(Contains(message, "= " + std::to_string(bad) + " is outside its valid range [1, 100]"));
    }
    // A whole number written as a float far outside the range is a range error, not a garbled value.
    const std::string message = buildError(sourceFilterSink(), oneSetting("source", "count", 1e30, 22));
    EXPECT_TRUE(BeginsWith(message, "job.toml:22: "));
    EXPECT_TRUE(Contains(message, "= 1e+30 is outside its valid range"));
}

TEST(ExecutionPlanErrors, FloatOutsideItsRange) {
    for (double bad : {-0.5, 10.5, std::nan(""), static_cast<double>(INFINITY)}) {
        const std::string message = buildError(sourceFilterSink(), oneSetting("source", "scale", bad, 30));
        EXPECT_TRUE(BeginsWith(message, "job.toml:30: "));
        EXPECT_TRUE(Contains(message, "source.scale"));
        EXPECT_TRUE(Contains(message, "outside its valid range [0, 10]"));
    }
}

TEST(ExecutionPlanErrors, WrongTypes) {
    struct Case {
        std::string key;
        ParamValue value;
        std::string expected;
    };
    const std::vector<Case> cases = {
        {"count", std::string("many"), "must be an integer, got \"many\""},
        {"count", 2.5, "must be an integer, got 2.5"},
        {"count", true, "must be an integer"},
        {"scale", std::string("big"), "must be a number"},
        {"mode", std::int64_t{3}, "must be a string, got 3"},
        {"verbose", std::int64_t{1}, "must be true or false, got 1"},
    };
    for (const Case& c : cases) {
        const std::string message = buildError(sourceFilterSink(), oneSetting("source", c.key, c.value, 40));
        EXPECT_TRUE(BeginsWith(message, "job.toml:40: ")) << c.key;
        EXPECT_TRUE(Contains(message, "'source." + c.key + "'"));
        EXPECT_TRUE(Contains(message, c.expected));
    }
}

TEST(ExecutionPlanErrors, StringNotAmongTheChoices) {
    const std::string message =
        buildError(sourceFilterSink(), oneSetting("source", "mode", std::string("medium"), 8));
    EXPECT_TRUE(BeginsWith(message, "job.toml:8: "));
    EXPECT_TRUE(Contains(message, "\"medium\" is not one of: fast, slow"));
}

TEST(ExecutionPlanErrors, ParametersForAPassNotInThePipeline) {
    const std::string message = buildError(sourceFilterSink(), oneSetting("ghost", "count", std::int64_t{3}, 31));
    EXPECT_TRUE(BeginsWith(message, "job.toml:30: "));  // where the [passes.ghost] table starts
    EXPECT_TRUE(Contains(message, "[passes.ghost]"));
}

TEST(ExecutionPlanErrors, TwoProducersOfOneBuffer) {
    const std::string message = buildError(
        pipeline({node("s1", "source", 2), node("s2", "source", 5), node("filter", "filter", 8)}, {"b"}));
    EXPECT_TRUE(BeginsWith(message, "job.toml:5: "));
    EXPECT_TRUE(Contains(message, "buffer 'a' is produced by both 's1' and 's2'"));
}

TEST(ExecutionPlanErrors, OtherStructuralMistakes) {
    EXPECT_TRUE(Contains(buildError(pipeline({node("s", "source", 2), node("s", "source", 4)}, {"a"})), "'s' appears twice"));
    EXPECT_TRUE(Contains(buildError(pipeline({node("s", "source", 2)}, {"image"})), "promises result 'image' but no pass produces it"));
    const std::string badInput = buildError(pipeline({node("s", "source", 2, {{"nope", "a"}})}, {"a"}));
    EXPECT_TRUE(BeginsWith(badInput, "job.toml:2: "));
    EXPECT_TRUE(Contains(badInput, "no input slot 'nope'"));
    const std::string badOutput = buildError(pipeline({node("s", "source", 2, {}, {{"nope", "a"}})}, {"a"}));
    EXPECT_TRUE(BeginsWith(badOutput, "job.toml:2: "));
    EXPECT_TRUE(Contains(badOutput, "no output slot 'nope'"));
}

TEST(ExecutionPlan, BindingsRenameBuffers) {
    const auto registry = validationRegistry();
    const Pipeline p = pipeline({node("left", "source", 1, {}, {{"a", "left_a"}}),
                                 node("right", "source", 2, {}, {{"a", "right_a"}}),
                                 node("filter", "filter", 3, {{"a", "right_a"}})},
                                {"b", "left_a"});
    const ExecutionPlan plan = ExecutionPlan::build(p, {}, "job.toml", registry);
    EXPECT_EQ(plan.passes()[2].dependencies, std::vector<int>{1});
    EXPECT_FALSE(plan.passes()[0].culled);  // produces a result directly
}

// --- Execution -------------------------------------------------------------

struct Flags {
    std::map<std::string, std::shared_ptr<std::atomic<bool>>> destroyed;
    std::map<std::string, std::atomic<int>> runs;
    // Only look-ups once passes run: the maps are shared between threads.
    std::shared_ptr<std::atomic<bool>> flag(const std::string& buffer) const { return destroyed.at(buffer); }
    void count(const std::string& pass) { runs.at(pass).fetch_add(1); }
};

// source: a = [0, count); twice: b = 2a; plus: c = a + 1; join: image = b + c;
// extra: reads a, writes "unused" which nobody reads and is no result.
std::vector<PassRegistration> diamondRegistry(Flags& flags, std::atomic<bool>& sawAFreedInJoin) {
    for (const char* b : {"a", "b", "c", "image", "unused"})
        flags.destroyed[b] = std::make_shared<std::atomic<bool>>(false);
    for (const char* p : {"source", "twice", "plus", "join", "extra"}) flags.runs[p] = 0;
    auto sourceBody = [&flags](PassContext& ctx) {
        flags.count("source");
        std::vector<double> v(static_cast<std::size_t>(ctx.params().getInt("count")));
        std::iota(v.begin(), v.end(), 0.0);
        ctx.createOutput<NumberBuffer>("a", std::move(v), flags.flag("a"));
        ctx.addItems(ctx.params().getInt("count"));
    };
    auto mapBody = [&flags](const std::string& name, const std::string& out, std::function<double(double)> f) {
        return [&flags, name, out, f](PassContext& ctx) {
            flags.count(name);
            EXPECT_FALSE(flags.flag("a")->load()) << name << " runs after its input was freed";
            const std::vector<double>& in = valuesOf(ctx, "a");
            std::vector<double> v(in.size());
            jobs::parallelFor(in.size(), 64, [&](std::size_t i) { v[i] = f(in[i]); });
            ctx.createOutput<NumberBuffer>(out, std::move(v), flags.flag(out));
            ctx.addItems(static_cast<std::int64_t>(in.size()));
        };
    };
    auto joinBody = [&flags, &sawAFreedInJoin](PassContext& ctx) {
        flags.count("join");
        sawAFreedInJoin = flags.flag("a")->load();
        const auto& b = valuesOf(ctx, "b");
        const auto& c = valuesOf(ctx, "c");
        std::vector<double> v(b.size());
        for (std::size_t i = 0; i < v.size(); ++i) v[i] = b[i] + c[i];
        ctx.createOutput<NumberBuffer>("image", std::move(v), flags.flag("image"));
    };
    auto extraBody = [&flags](PassContext& ctx) {
        flags.count("extra");
        ctx.createOutput<NumberBuffer>("unused", std::vector<double>{1.0}, flags.flag("unused"));
    };
    return {
        makePass("source", {}, {numbers("a")}, sourceBody,
                 {{"count", ParamType::Int, std::int64_t{4}, 1, 1e6, {}, "how many numbers"}}),
        makePass("twice", {numbers("a")}, {numbers("b")}, mapBody("twice", "b", [](double x) { return 2 * x; })),
        makePass("plus", {numbers("a")}, {numbers("c")}, mapBody("plus", "c", [](double x) { return x + 1; })),
        makePass("join", {numbers("b"), numbers("c")}, {numbers("image")}, joinBody),
        makePass("extra", {numbers("a")}, {numbers("unused")}, extraBody),
    };
}

Pipeline diamond() {
    return pipeline({node("source", "source", 1), node("twice", "twice", 2), node("plus", "plus", 3),
                     node("extra", "extra", 4), node("join", "join", 5)},
                    {"image"});
}

TEST(ExecutionPlan, CullsPassesThatFeedNoResult) {
    Flags flags;
    std::atomic<bool> unusedFlag{false};
    const auto registry = diamondRegistry(flags, unusedFlag);
    const ExecutionPlan plan = ExecutionPlan::build(diamond(), {}, "job.toml", registry);
    for (const PlannedPass& p : plan.passes()) EXPECT_EQ(p.culled, p.node.instance == "extra") << p.node.instance;

    // The same pass is kept once its output is a result.
    Pipeline withExtra = diamond();
    withExtra.results.push_back("unused");
    const ExecutionPlan kept = ExecutionPlan::build(withExtra, {}, "job.toml", registry);
    for (const PlannedPass& p : kept.passes()) EXPECT_FALSE(p.culled) << p.node.instance;
}

TEST(ExecutionPlan, DotListsEveryPassAndEdge) {
    Flags flags;
    std::atomic<bool> unusedFlag{false};
    const auto registry = diamondRegistry(flags, unusedFlag);
    const std::string dot = ExecutionPlan::build(diamond(), {}, "job.toml", registry).toDot();
    EXPECT_TRUE(BeginsWith(dot, "digraph"));
    for (const std::string pass : {"\"source\"", "\"twice\"", "\"plus\"", "\"extra\"", "\"join\""})
        EXPECT_TRUE(Contains(dot, pass + " [label=")) << pass;
    for (const char* edge : {"\"source\" -> \"twice\"", "\"source\" -> \"plus\"", "\"source\" -> \"extra\"",
                             "\"twice\" -> \"join\"", "\"plus\" -> \"join\"", "\"join\" -> \"result:image\""})
        EXPECT_TRUE(Contains(dot, edge)) << edge;
    EXPECT_TRUE(Contains(dot, "style=dashed"));  // the culled pass is drawn differently
}

TEST(Execute, RunsADiamondProducesResultsAndFreesBuffers) {
    const Scene scene;
    for (int threads : {1, 2, 4}) {
        jobs::ThreadLimit limit(threads);
        for (int repeat = 0; repeat < 5; ++repeat) {
            Flags flags;
            std::atomic<bool> sawAFreedInJoin{false};
            const auto registry = diamondRegistry(flags, sawAFreedInJoin);
            const ExecutionPlan plan =
                ExecutionPlan::build(diamond(), oneSetting("source", "count", std::int64_t{1000}, 7), "job.toml",
                                     registry);
            const RunResult result = execute(plan, scene, nullptr, RunOptions{});

            ASSERT_EQ(result.results.size(), 1u);
            const BufferHandle& image = result.results.at("image");
            EXPECT_EQ(image.type, "Numbers");
            const auto* values = static_cast<const NumberBuffer*>(image.data.get());
            ASSERT_NE(values, nullptr);
            ASSERT_EQ(values->values.size(), 1000u);
            for (std::size_t i = 0; i < 1000; ++i) ASSERT_EQ(values->values[i], 3.0 * static_cast<double>(i) + 1.0);

            for (const char* p : {"source", "twice", "plus", "join"}) EXPECT_EQ(flags.runs.at(p).load(), 1) << p;
            EXPECT_EQ(flags.runs.at("extra").load(), 0);  // culled
            // 'a' goes once both its readers are done, before 'join' starts.
            EXPECT_TRUE(sawAFreedInJoin.load());
            // Nothing but the results outlives the run.
            EXPECT_TRUE(flags.flag("b")->load());
            EXPECT_TRUE(flags.flag("c")->load());
            EXPECT_FALSE(flags.flag("image")->load());  // results are handed back alive

            ASSERT_EQ(result.stats.size(), 4u);
            EXPECT_EQ(result.stats.front().instance, "source");
            EXPECT_EQ(result.stats.back().instance, "join");
            for (const PassStats& s : result.stats) {
                EXPECT_GE(s.wallSeconds, 0.0) << s.instance;
                EXPECT_GE(s.startSeconds, 0.0) << s.instance;
                EXPECT_LE(s.startSeconds + s.wallSeconds, result.wallSeconds + 1e-6) << s.instance;
                EXPECT_GE(s.outputBytes, 1000 * sizeof(double)) << s.instance;
                EXPECT_EQ(s.items, s.instance == "join" ? 0 : 1000) << s.instance;
            }
        }
    }
}

TEST(Execute, BooksParallelWorkToThePass) {
    std::atomic<double> sink{0.0};
    const std::vector<PassRegistration> registry = {
        makePass("busy", {}, {numbers("image")}, [&](PassContext& ctx) {
            jobs::parallelFor(64, 1, [&](std::size_t i) {
                double x = static_cast<double>(i);
                for (int k = 0; k < 50000; ++k) x = std::sqrt(x * x + 1.0) - 0.999 * x;
                sink.store(x);
            });
            ctx.addItems(64);
            ctx.createOutput<NumberBuffer>("image", std::vector<double>(8), nullptr);
        }),
    };
    const ExecutionPlan plan = ExecutionPlan::build(pipeline({node("busy", "busy", 1)}, {"image"}), {}, "job.toml",
                                                    registry);
    const RunResult result = execute(plan, Scene{}, nullptr, RunOptions{});
    ASSERT_EQ(result.stats.size(), 1u);
    const PassStats& s = result.stats[0];
    EXPECT_EQ(s.instance, "busy");
    EXPECT_EQ(s.pass, "busy");
    EXPECT_EQ(s.items, 64);
    EXPECT_GT(s.cpuSeconds, 0.0);
    EXPECT_GT(s.wallSeconds, 0.0);
    EXPECT_EQ(s.outputBytes, 8 * sizeof(double));
}

TEST(Execute, PassesSeedParametersAndProgressThrough) {
    std::mutex mutex;
    std::vector<std::pair<std::string, double>> progress;
    std::uint64_t seenSeed = 0;
    int seenFilmWidth = 0;
    const std::vector<PassRegistration> registry = {
        makePass("probe", {}, {numbers("image")}, [&](PassContext& ctx) {
            seenSeed = ctx.seed();
            seenFilmWidth = ctx.filmSettings().width;
            ctx.reportProgress(0.5);
            ctx.createOutput<NumberBuffer>("image", std::vector<double>{ctx.params().getFloat("gain")}, nullptr);
        }, {{"gain", ParamType::Float, 1.0, 0.0, 100.0, {}, "gain"}}),
    };
    JobParams params;
    params.values["probe"]["gain"] = {2.5, "job.toml:3"};
    const ExecutionPlan plan = ExecutionPlan::build(pipeline({node("probe", "probe", 1)}, {"image"}), params,
                                                    "job.toml", registry);
    RunOptions options;
    options.seed = 1234;
    options.film.width = 77;
    options.progress = [&](const std::string& instance, double fraction) {
        std::lock_guard lock(mutex);
        progress.emplace_back(instance, fraction);
    };
    const RunResult result = execute(plan, Scene{}, nullptr, options);
    EXPECT_EQ(seenSeed, 1234u);
    EXPECT_EQ(seenFilmWidth, 77);
    ASSERT_EQ(progress.size(), 1u);
    EXPECT_EQ(progress[0].first, "probe");
    EXPECT_EQ(progress[0].second, 0.5);
    EXPECT_EQ(static_cast<const NumberBuffer*>(result.results.at("image").data.get())->values[0], 2.5);
}

TEST(Execute, ExceptionInAPassPropagatesAndStopsItsSuccessors) {
    std::atomic<bool> sinkRan{false};
    const std::vector<PassRegistration> registry = {
        makePass("source", {}, {numbers("a")}, [](PassContext& ctx) {
            ctx.createOutput<NumberBuffer>("a", std::vector<double>{1.0}, nullptr);
        }),
        makePass("filter", {numbers("a")}, {numbers("b")}, [](PassContext&) {
            throw std::runtime_error("filter failed on purpose");
        }),
        makePass("sink", {numbers("b")}, {numbers("image")}, [&](PassContext& ctx) {
            sinkRan = true;
            ctx.createOutput<NumberBuffer>("image", std::vector<double>{}, nullptr);
        }),
    };
    const ExecutionPlan plan = ExecutionPlan::build(sourceFilterSink(), {}, "job.toml", registry);
    try {
        execute(plan, Scene{}, nullptr, RunOptions{});
        FAIL() << "execute() returned although a pass threw";
    } catch (const std::runtime_error& e) {
        EXPECT_STREQ(e.what(), "filter failed on purpose");
    }
    EXPECT_FALSE(sinkRan.load());
}

TEST(Execute, APassThatDoesNotProduceItsOutputIsAnError) {
    const std::vector<PassRegistration> registry = {
        makePass("lazy", {}, {numbers("image")}, [](PassContext&) {}),
    };
    const ExecutionPlan plan =
        ExecutionPlan::build(pipeline({node("lazy", "lazy", 1)}, {"image"}), {}, "job.toml", registry);
    try {
        execute(plan, Scene{}, nullptr, RunOptions{});
        FAIL() << "a missing output went unnoticed";
    } catch (const std::logic_error& e) {
        EXPECT_TRUE(Contains(e.what(), "'lazy' did not produce its output 'image'"));
    }
}

TEST(Execute, ContextChecksSlotsAndRayQueries) {
    const std::vector<PassRegistration> registry = {
        makePass("wrong_type", {}, {numbers("image")}, [](PassContext& ctx) { ctx.createOutput<LabelBuffer>("image"); }),
        makePass("wrong_slot", {}, {numbers("image")},
                 [](PassContext& ctx) { ctx.createOutput<NumberBuffer>("other", std::vector<double>{}, nullptr); }),
        makePass("tracer", {}, {numbers("image")}, [](PassContext& ctx) { (void)ctx.rays(); }),
    };
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"wrong_type", "output 'image' is Numbers, not Label"},
        {"wrong_slot", "undeclared output 'other'"},
        {"tracer", "'tracer' traces rays"},
    };
    for (const auto& [pass, expected] : cases) {
        const ExecutionPlan plan =
            ExecutionPlan::build(pipeline({node(pass, pass, 1)}, {"image"}), {}, "job.toml", registry);
        try {
            execute(plan, Scene{}, nullptr, RunOptions{});
            ADD_FAILURE() << pass << " was not stopped";
        } catch (const std::logic_error& e) {
            EXPECT_TRUE(Contains(e.what(), expected));
        }
    }
}

}  // namespace
}  // namespace fg
