// What a pass is: a named unit of work that declares its typed input and output
// buffers and its parameters (type, default, valid range, one-line doc), and
// does its work through jobs/ over SoA buffers. Passes are registered in one
// table (passes/registry.cpp); pipelines wire them by buffer names.
#pragma once

#include "engine/image/film.h"

#include <any>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <typeindex>
#include <variant>
#include <vector>

namespace fg {

struct Scene;
class RayQuery;

enum class ParamType { Int, Float, Bool, String };
using ParamValue = std::variant<std::int64_t, double, bool, std::string>;

struct ParamSpec {
    std::string name;
    ParamType type = ParamType::Int;
    ParamValue defaultValue;
    double minValue = -1e300;  // inclusive range for Int and Float
    double maxValue = 1e300;
    std::vector<std::string> choices;  // allowed values for String (empty = any)
    std::string doc;
};

// A buffer slot: its name in the pipeline and the buffer type it carries.
struct SlotSpec {
    std::string name;
    std::string type;  // e.g. "Film", "PhotonBuffer"; must match between producer and consumer
    std::string doc;
    // Output: the pass can hand the buffer over in batches (PassContext::emitBatch).
    // Input: the pass reads it in Pass::consumeBatch, one batch at a time. A buffer
    // whose producer and every reader say so is streamed: never stored whole.
    bool streamable = false;
};

struct PassSpec {
    std::string name;
    std::string doc;
    std::vector<SlotSpec> inputs;
    std::vector<SlotSpec> outputs;
    std::vector<ParamSpec> params;
};

std::string toString(ParamType type);
std::string toString(const ParamValue& value);
// "[1, 1048576]": a numeric parameter's valid range as a reader would write it.
std::string describeRange(const ParamSpec& spec);

// Resolved parameter values of one pass instance (defaults + job file + --set).
class PassParams {
public:
    void set(const std::string& name, ParamValue value) { values_[name] = std::move(value); }
    std::int64_t getInt(const std::string& name) const;
    double getFloat(const std::string& name) const;
    bool getBool(const std::string& name) const;
    const std::string& getString(const std::string& name) const;
    const std::map<std::string, ParamValue>& values() const { return values_; }

private:
    const ParamValue& at(const std::string& name) const;
    std::map<std::string, ParamValue> values_;
};

// A type-erased buffer owned by the scheduler.
struct BufferHandle {
    std::string type;
    std::shared_ptr<void> data;
    std::function<std::size_t()> bytes;
};

// Maps C++ buffer types to the type names used in slot declarations.
template <class T>
struct BufferTypeName;
template <>
struct BufferTypeName<Film> {
    static constexpr const char* value = "Film";
};

// Everything a running pass may touch: the scene (read-only), its parameters,
// its declared inputs and outputs, and counters for the profiler.
class PassContext {
public:
    PassContext(const Scene& scene, const RayQuery& rays, const FilmSettings& film, std::uint64_t seed,
                const PassParams& params, std::map<std::string, BufferHandle*> inputs,
                std::map<std::string, BufferHandle*> outputs, std::string instanceName);
    // Without ray queries (rays may be null), for pipelines whose passes trace no rays.
    PassContext(const Scene& scene, const RayQuery* rays, const FilmSettings& film, std::uint64_t seed,
                const PassParams& params, std::map<std::string, BufferHandle*> inputs,
                std::map<std::string, BufferHandle*> outputs, std::string instanceName);

    const Scene& scene() const { return scene_; }
    // Throws std::logic_error when the context was made without ray queries.
    const RayQuery& rays() const;
    const FilmSettings& filmSettings() const { return film_; }
    std::uint64_t seed() const { return seed_; }
    const PassParams& params() const { return params_; }
    const std::string& instanceName() const { return instance_; }

    template <class T>
    const T& input(const std::string& slot) const {
        const BufferHandle* handle = checked(inputs_, slot, BufferTypeName<T>::value, "input");
        if (!handle->data)
            throw std::logic_error("input '" + slot + "' of '" + instance_ + "' is streamed: read it in consumeBatch");
        return *static_cast<const T*>(handle->data.get());
    }
    // Creates the output buffer (constructed from args) and returns it.
    template <class T, class... Args>
    T& createOutput(const std::string& slot, Args&&... args) {
        BufferHandle* handle = checked(outputs_, slot, BufferTypeName<T>::value, "output");
        auto object = std::make_shared<T>(std::forward<Args>(args)...);
        T& ref = *object;
        handle->data = object;
        handle->bytes = [raw = object.get()] { return raw->bytes(); };
        return ref;
    }

    // Work items processed (photons, samples, ...), for items/s in the report.
    void addItems(std::int64_t n) { items_ += n; }
    std::int64_t items() const { return items_; }
    // Named counters reported with the pass's statistics (e.g. path vertices); pass thread only.
    void addCounter(const std::string& name, std::int64_t n) { counters_[name] += n; }
    const std::map<std::string, std::int64_t>& counters() const { return counters_; }
    // Streamed outputs. When the scheduler streams an output (its producer slot and
    // every reader's slot are streamable), the pass must not createOutput() it but
    // hand it over with emitBatch(), as often as it likes; each batch is given to
    // every reader's consumeBatch() before emitBatch returns, then dropped.
    bool streamed(const std::string& outputSlot) const;
    template <class T>
    void emitBatch(const std::string& slot, std::shared_ptr<const T> batch) {
        checked(outputs_, slot, BufferTypeName<T>::value, "output");
        if (!streamed(slot)) throw std::logic_error("output '" + slot + "' of '" + instance_ + "' is not streamed");
        const std::size_t bytes = batch->bytes();
        emitErased(slot, std::const_pointer_cast<void>(std::static_pointer_cast<const void>(std::move(batch))), bytes);
    }
    using BatchSink = std::function<void(const std::string& slot, std::shared_ptr<void> batch, std::size_t bytes)>;
    void setBatchSink(std::vector<std::string> streamedOutputs, BatchSink sink) {
        streamedOutputs_ = std::move(streamedOutputs);
        batchSink_ = std::move(sink);
    }

    // Progress in [0, 1] of a long pass, shown as a bar on a terminal.
    void reportProgress(double fraction) const;
    void setProgressSink(std::function<void(const std::string&, double)> sink) { progress_ = std::move(sink); }

private:
    static BufferHandle* checked(const std::map<std::string, BufferHandle*>& slots, const std::string& slot,
                                 const char* type, const char* kind);
    void emitErased(const std::string& slot, std::shared_ptr<void> batch, std::size_t bytes);
    const Scene& scene_;
    const RayQuery* rays_;
    const FilmSettings& film_;
    std::uint64_t seed_;
    const PassParams& params_;
    std::map<std::string, BufferHandle*> inputs_;
    std::map<std::string, BufferHandle*> outputs_;
    std::string instance_;
    std::int64_t items_ = 0;
    std::map<std::string, std::int64_t> counters_;
    std::function<void(const std::string&, double)> progress_;
    std::vector<std::string> streamedOutputs_;
    BatchSink batchSink_;
};

class Pass {
public:
    virtual ~Pass() = default;
    // Called once per batch of each streamable input before run(): the batch is
    // context.input<T>(slot) for the duration of the call. A stored (not streamed)
    // input arrives as one batch holding the whole buffer.
    virtual void consumeBatch(PassContext& context, const std::string& slot) {
        (void)context;
        (void)slot;
    }
    virtual void run(PassContext& context) = 0;
};

struct PassRegistration {
    PassSpec spec;
    std::function<std::unique_ptr<Pass>()> create;
};

// The one registry table, defined in passes/registry.cpp.
const std::vector<PassRegistration>& passRegistry();
const PassRegistration* findPass(const std::string& name);

// A pass instance in a pipeline: buffers are bound by name; by default a slot
// binds to the buffer of the same name.
struct PipelineNode {
    std::string instance;  // unique within the pipeline; parameters live under [passes.<instance>]
    std::string pass;      // registered pass name
    std::map<std::string, std::string> inputBindings;   // slot -> buffer
    std::map<std::string, std::string> outputBindings;  // slot -> buffer
    int sourceLine = 0;    // where a job file defined it, for messages
};

struct Pipeline {
    std::string name;
    std::string doc;
    std::vector<PipelineNode> nodes;
    std::vector<std::string> results;  // buffers the run must produce (the images written out)
    bool streamBatches = true;  // stream buffers whose producer and readers allow it (job key stream_batches)
};

// Built-in pipelines (passes/pipelines.cpp).
const std::vector<Pipeline>& builtinPipelines();
const Pipeline* findPipeline(const std::string& name);

}  // namespace fg
