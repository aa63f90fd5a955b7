// Helpers for tests that run single passes on hand-made buffers, or pipelines
// built in the test (with test-only passes alongside the registered ones).
#pragma once

#include "engine/image/film.h"
#include "engine/core/pass.h"
#include "engine/scene/scene.h"
#include "engine/core/scheduler.h"

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace fg::test {

// A test pass whose work is given as functions: run() and, for streamed or
// streamable inputs, consumeBatch().
using PassBody = std::function<void(PassContext&)>;
using BatchBody = std::function<void(PassContext&, const std::string&)>;
class LambdaPass : public Pass {
public:
    LambdaPass(PassBody run, BatchBody consume) : run_(std::move(run)), consume_(std::move(consume)) {}
    void consumeBatch(PassContext& ctx, const std::string& slot) override {
        if (consume_) consume_(ctx, slot);
    }
    void run(PassContext& ctx) override { run_(ctx); }

private:
    PassBody run_;
    BatchBody consume_;
};
inline PassRegistration lambdaPass(PassSpec spec, PassBody run, BatchBody consume = {}) {
    return {std::move(spec), [run = std::move(run), consume = std::move(consume)] {
                return std::make_unique<LambdaPass>(run, consume);
            }};
}

template <class T>
BufferHandle makeBuffer(std::shared_ptr<T> data) {
    BufferHandle handle;
    handle.type = BufferTypeName<T>::value;
    handle.bytes = [raw = data.get()] { return raw->bytes(); };
    handle.data = std::move(data);
    return handle;
}

template <class T>
const T& bufferAs(const BufferHandle& handle) {
    return *static_cast<const T*>(handle.data.get());
}

// Runs one pass with its parameter defaults overridden by `params` (name ->
// value) on the given input buffers (slot -> buffer); returns its outputs by slot.
std::map<std::string, BufferHandle> runPass(const PassRegistration& pass, const Scene& scene, const RayQuery* rays,
                                            const FilmSettings& film, std::map<std::string, BufferHandle> inputs,
                                            const std::map<std::string, ParamValue>& params = {},
                                            std::uint64_t seed = 1);

// Runs `pipeline` against `registry` ("instance.param" -> value) and returns
// the buffer `result`.
BufferHandle runPipeline(const Scene& scene, const Pipeline& pipeline, const std::vector<PassRegistration>& registry,
                         const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                         const std::string& result, std::uint64_t seed = 1, int threads = 0);

}  // namespace fg::test
