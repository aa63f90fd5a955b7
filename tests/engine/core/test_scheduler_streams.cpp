// Streamed buffers: a producer that emits batches and readers that consume them
// run as one task; the buffer is never stored whole, and falls back to being
// stored when any reader cannot take batches, when streaming is switched off,
// or when fusing the reader into the producer's task would make a cycle.
#include "engine/core/scheduler.h"

#include "tests/support/pass_helpers.h"

#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace fg {
namespace {

struct Batch {
    std::vector<double> values;
    std::shared_ptr<std::atomic<int>> alive;
    Batch(std::vector<double> v, std::shared_ptr<std::atomic<int>> counter) : values(std::move(v)), alive(std::move(counter)) {
        if (alive) ++*alive;
    }
    ~Batch() {
        if (alive) --*alive;
    }
    Batch(const Batch&) = delete;
    Batch& operator=(const Batch&) = delete;
    std::size_t bytes() const { return values.size() * sizeof(double); }
};

}  // namespace

template <>
struct BufferTypeName<Batch> {
    static constexpr const char* value = "Batch";
};

namespace {

using Body = test::PassBody;
using test::BatchBody;

PassRegistration makePass(const std::string& name, std::vector<SlotSpec> inputs, std::vector<SlotSpec> outputs,
                          Body run, BatchBody consume = {}) {
    PassSpec spec;
    spec.name = name;
    spec.doc = "test pass " + name;
    spec.inputs = std::move(inputs);
    spec.outputs = std::move(outputs);
    return test::lambdaPass(std::move(spec), std::move(run), std::move(consume));
}

SlotSpec batches(const std::string& name, bool streamable) { return {name, "Batch", "", streamable}; }

PipelineNode node(const std::string& instance, const std::string& pass) {
    PipelineNode n;
    n.instance = instance;
    n.pass = pass;
    return n;
}

// The producer's five batches: batch b holds b * 10 + i for i < b + 1.
std::vector<std::vector<double>> producedBatches() {
    std::vector<std::vector<double>> all;
    for (int b = 0; b < 5; ++b) {
        std::vector<double> values;
        for (int i = 0; i <= b; ++i) values.push_back(b * 10 + i);
        all.push_back(values);
    }
    return all;
}

struct Recorder {
    std::shared_ptr<std::atomic<int>> aliveBatches = std::make_shared<std::atomic<int>>(0);
    std::vector<std::vector<double>> seen;  // by the streaming reader, in order
    std::vector<double> biasSeen;           // the reader's other input, read during consumeBatch
    int maxAliveWhileConsuming = 0;
    bool readOutsideBatchThrew = false;
    bool producerWasStreamed = false;
};

// source --a--> sum (streamable reader, also reading `bias`) --image
// bias -----------^            [tail: optional non-streaming reader of a]
std::vector<PassRegistration> registry(Recorder& rec) {
    const Body source = [&rec](PassContext& ctx) {
        rec.producerWasStreamed = ctx.streamed("a");
        if (!ctx.streamed("a")) {
            auto& whole = ctx.createOutput<Batch>("a", std::vector<double>{}, rec.aliveBatches);
            for (const auto& b : producedBatches()) whole.values.insert(whole.values.end(), b.begin(), b.end());
            return;
        }
        for (const auto& b : producedBatches()) {
            ctx.emitBatch<Batch>("a", std::make_shared<const Batch>(b, rec.aliveBatches));
            // Handed over and dropped: nothing of the stream is kept.
            EXPECT_EQ(rec.aliveBatches->load(), 0);
        }
    };
    const BatchBody consume = [&rec](PassContext& ctx, const std::string& slot) {
        EXPECT_EQ(slot, "a");
        rec.seen.push_back(ctx.input<Batch>("a").values);
        rec.biasSeen = ctx.input<Batch>("bias").values;
        rec.maxAliveWhileConsuming = std::max(rec.maxAliveWhileConsuming, rec.aliveBatches->load());
    };
    const Body sum = [&rec](PassContext& ctx) {
        try {
            (void)ctx.input<Batch>("a");
        } catch (const std::logic_error&) {
            rec.readOutsideBatchThrew = true;
        }
        std::vector<double> out;
        for (const auto& b : rec.seen) out.insert(out.end(), b.begin(), b.end());
        for (double& v : out) v += rec.biasSeen.at(0);
        ctx.createOutput<Batch>("image", out, nullptr);
    };
    return {
        makePass("source", {}, {batches("a", true)}, source),
        makePass("bias", {}, {batches("bias", false)},
                 [](PassContext& ctx) { ctx.createOutput<Batch>("bias", std::vector<double>{0.5}, nullptr); }),
        makePass("sum", {batches("a", true), batches("bias", false)}, {batches("image", false)}, sum, consume),
        makePass("tail", {batches("a", false)}, {batches("tail", false)},
                 [](PassContext& ctx) { ctx.createOutput<Batch>("tail", ctx.input<Batch>("a").values, nullptr); }),
    };
}

std::vector<double> expectedImage() {
    std::vector<double> out;
    for (const auto& b : producedBatches())
        for (double v : b) out.push_back(v + 0.5);
    return out;
}

const std::vector<double>& imageOf(const RunResult& result) {
    return static_cast<const Batch*>(result.results.at("image").data.get())->values;
}

Pipeline streamPipeline(bool withTail) {
    Pipeline p;
    p.name = "stream-test";
    p.nodes = {node("source", "source"), node("bias", "bias"), node("sum", "sum")};
    p.results = {"image"};
    if (withTail) {
        p.nodes.push_back(node("tail", "tail"));
        p.results.push_back("tail");
    }
    return p;
}

TEST(Streams, ReaderConsumesEveryBatchInOrderAndNothingIsStored) {
    const Scene scene;
    for (int threads : {1, 2, 4}) {
        jobs::ThreadLimit limit(threads);
        Recorder rec;
        const auto passes = registry(rec);
        const ExecutionPlan plan = ExecutionPlan::build(streamPipeline(false), {}, "job.toml", passes);
        ASSERT_TRUE(plan.streamed("a"));
        EXPECT_FALSE(plan.streamed("bias"));
        EXPECT_EQ(plan.passes()[2].streamHost, 0);
        EXPECT_EQ(plan.passes()[0].streamedOutputs, std::vector<std::string>{"a"});
        EXPECT_NE(plan.toDot().find("(batches)"), std::string::npos);

        const RunResult result = execute(plan, scene, nullptr, RunOptions{});
        EXPECT_TRUE(rec.producerWasStreamed);
        EXPECT_EQ(rec.seen, producedBatches());
        EXPECT_EQ(rec.biasSeen, std::vector<double>{0.5});
        EXPECT_EQ(rec.maxAliveWhileConsuming, 1);  // only the batch being consumed
        EXPECT_TRUE(rec.readOutsideBatchThrew);
        EXPECT_EQ(imageOf(result), expectedImage());
        EXPECT_EQ(rec.aliveBatches->load(), 0);
        ASSERT_EQ(result.stats.size(), 3u);
        for (const PassStats& s : result.stats) {
            EXPECT_GE(s.wallSeconds, 0.0) << s.instance;
            if (s.instance == "source") {
                EXPECT_EQ(s.batchesEmitted, 5);
                EXPECT_EQ(s.outputBytes, 5 * sizeof(double));  // the largest batch
            }
        }
    }
}

TEST(Streams, AReaderThatCannotTakeBatchesKeepsTheBufferStored) {
    const Scene scene;
    Recorder rec;
    const auto passes = registry(rec);
    const ExecutionPlan plan = ExecutionPlan::build(streamPipeline(true), {}, "job.toml", passes);
    EXPECT_FALSE(plan.streamed("a"));
    EXPECT_EQ(plan.passes()[2].streamHost, -1);
    const RunResult result = execute(plan, scene, nullptr, RunOptions{});
    EXPECT_FALSE(rec.producerWasStreamed);
    // The streaming reader got the stored buffer as one batch.
    ASSERT_EQ(rec.seen.size(), 1u);
    EXPECT_EQ(imageOf(result), expectedImage());
    EXPECT_EQ(static_cast<const Batch*>(result.results.at("tail").data.get())->values.size(), expectedImage().size());
}

TEST(Streams, SwitchedOffThePipelineStoresEverything) {
    const Scene scene;
    Recorder rec;
    const auto passes = registry(rec);
    Pipeline p = streamPipeline(false);
    p.streamBatches = false;
    const ExecutionPlan plan = ExecutionPlan::build(p, {}, "job.toml", passes);
    EXPECT_FALSE(plan.streamed("a"));
    const RunResult result = execute(plan, scene, nullptr, RunOptions{});
    EXPECT_FALSE(rec.producerWasStreamed);
    EXPECT_EQ(rec.seen.size(), 1u);
    EXPECT_EQ(imageOf(result), expectedImage());
}

TEST(Streams, NotFusedWhenTheReaderWaitsOnSomethingDownstreamOfTheProducer) {
    // producer --a (streamable)--> reader;  producer --b--> middle --c--> reader.
    // Running the reader inside the producer would need c before the producer ends.
    std::vector<std::vector<double>> seen;
    const std::vector<PassRegistration> passes = {
        makePass("producer", {}, {batches("a", true), batches("b", false)},
                 [](PassContext& ctx) {
                     if (ctx.streamed("a")) ADD_FAILURE() << "a must not be streamed";
                     ctx.createOutput<Batch>("a", std::vector<double>{1, 2}, nullptr);
                     ctx.createOutput<Batch>("b", std::vector<double>{3}, nullptr);
                 }),
        makePass("middle", {batches("b", false)}, {batches("c", false)},
                 [](PassContext& ctx) { ctx.createOutput<Batch>("c", ctx.input<Batch>("b").values, nullptr); }),
        makePass("reader", {batches("a", true), batches("c", false)}, {batches("image", false)},
                 [&](PassContext& ctx) {
                     std::vector<double> out = seen.at(0);
                     out.push_back(ctx.input<Batch>("c").values.at(0));
                     ctx.createOutput<Batch>("image", out, nullptr);
                 },
                 [&](PassContext& ctx, const std::string&) { seen.push_back(ctx.input<Batch>("a").values); }),
    };
    Pipeline p;
    p.name = "no-fuse";
    p.nodes = {node("producer", "producer"), node("middle", "middle"), node("reader", "reader")};
    p.results = {"image"};
    const ExecutionPlan plan = ExecutionPlan::build(p, {}, "job.toml", passes);
    EXPECT_FALSE(plan.streamed("a"));
    const RunResult result = execute(plan, Scene{}, nullptr, RunOptions{});
    EXPECT_EQ(imageOf(result), (std::vector<double>{1, 2, 3}));
}

TEST(Streams, AHostedReaderGetsItsHostsStoredOutputsAfterTheHostRan) {
    // producer --a (streamed)--> reader, producer --b (stored: also a result)--> reader:
    // the reader consumes b as one batch, which exists only once the producer has run.
    std::vector<std::string> order;
    const std::vector<PassRegistration> passes = {
        makePass("producer", {}, {batches("a", true), batches("b", true)},
                 [&](PassContext& ctx) {
                     EXPECT_TRUE(ctx.streamed("a"));
                     EXPECT_FALSE(ctx.streamed("b"));
                     ctx.emitBatch<Batch>("a", std::make_shared<const Batch>(std::vector<double>{1}, nullptr));
                     ctx.createOutput<Batch>("b", std::vector<double>{2}, nullptr);
                     order.push_back("producer");
                 }),
        makePass("reader", {batches("a", true), batches("b", true)}, {batches("image", false)},
                 [&](PassContext& ctx) {
                     order.push_back("run");
                     ctx.createOutput<Batch>("image", std::vector<double>{}, nullptr);
                 },
                 [&](PassContext& ctx, const std::string& slot) {
                     order.push_back(slot + "=" + std::to_string(ctx.input<Batch>(slot).values.at(0)).substr(0, 1));
                 }),
    };
    Pipeline p;
    p.name = "host-outputs";
    p.nodes = {node("producer", "producer"), node("reader", "reader")};
    p.results = {"image", "b"};
    const ExecutionPlan plan = ExecutionPlan::build(p, {}, "job.toml", passes);
    EXPECT_TRUE(plan.streamed("a"));
    EXPECT_FALSE(plan.streamed("b"));
    execute(plan, Scene{}, nullptr, RunOptions{});
    EXPECT_EQ(order, (std::vector<std::string>{"a=1", "producer", "b=2", "run"}));
}

TEST(Streams, EmittingOnAStoredOutputIsAnError) {
    const std::vector<PassRegistration> passes = {
        makePass("producer", {}, {batches("image", true)},
                 [](PassContext& ctx) {
                     ctx.emitBatch<Batch>("image", std::make_shared<const Batch>(std::vector<double>{1}, nullptr));
                 }),
    };
    Pipeline p;
    p.name = "bad-emit";
    p.nodes = {node("producer", "producer")};
    p.results = {"image"};  // a result is always stored
    const ExecutionPlan plan = ExecutionPlan::build(p, {}, "job.toml", passes);
    EXPECT_FALSE(plan.streamed("image"));
    EXPECT_THROW(execute(plan, Scene{}, nullptr, RunOptions{}), std::logic_error);
}

}  // namespace
}  // namespace fg
