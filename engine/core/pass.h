// What a pass is: a named unit of work that declares its typed input, output
// and in-out buffers and its parameters (type, default, valid range, one-line
// doc), checks what it can before any work (preflight), and does its work
// through jobs/ over SoA buffers. The program hands the engine a Registry of
// passes and pipelines (passes/registry.cpp builds the built-in one); pipelines
// wire passes by buffer names.
#pragma once

#include "engine/core/memory.h"
#include "engine/image/film.h"

#include <algorithm>
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

struct Camera;
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
    // A scene-file rendering hint this parameter takes when the job leaves it
    // unset: "sample_count" (Mitsuba's sampler) or "max_depth" (its integrator,
    // already converted). Empty: scene hints never reach it.
    std::string sceneHint;
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
    // Input: the pass also runs when no pass produces the buffer (PassContext::hasInput).
    bool optional = false;
};

struct PassSpec {
    std::string name;
    std::string doc;
    std::vector<SlotSpec> inputs;
    std::vector<SlotSpec> outputs;
    // Slots read and written in place (a model refined by the pass). The write is
    // a new version of the buffer: readers of the old version run before it.
    std::vector<SlotSpec> inouts;
    std::vector<ParamSpec> params;
    // Conditions the pass may raise while it runs (PassContext::signal); a repeat
    // block may end on one (`until = "instance.signal"`).
    std::vector<std::string> signals;
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

class PassContext;
// What a pass may check before any work: the scene, its own parameters and those
// of the passes producing its inputs. Throws InputError naming `source`.
struct PreflightContext {
    const Scene& scene;
    const PassParams& params;
    std::string instance;
    std::string source;  // "job.toml:12" or the job file
    // The parameters and pass name of the producer of an input slot; null when
    // the slot is unbound, imported from a file or its producer is not a pass.
    std::function<const PassParams*(const std::string& slot)> producerParams;
    std::function<std::string(const std::string& slot)> producerPass;
    FilmSettings film{};  // the job's film, as the render will make it
    // Whether an output slot of this pass is handed over batch by batch (never stored whole).
    std::function<bool(const std::string& slot)> outputStreamed;
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
    // The scene's camera with the film's size: the job's [film] may override
    // the resolution the scene file gives.
    Camera filmCamera() const;
    std::uint64_t seed() const { return seed_; }
    const PassParams& params() const { return params_; }
    const std::string& instanceName() const { return instance_; }
    // The `pass` part of random-stream keys: the FNV-1a hash of the instance
    // name. A repeat block's instances are named "block[i].name", so every
    // iteration draws its own numbers; a pass outside any block whose instance
    // is named after the pass keeps the key it always had.
    std::uint64_t streamKey() const;
    // The repeat-block iteration of this instance, -1 outside blocks.
    int iteration() const { return iteration_; }
    void setIteration(int iteration) { iteration_ = iteration; }

    // Whether an optional input is bound to a buffer in this run.
    bool hasInput(const std::string& slot) const {
        const auto it = inputs_.find(slot);
        return it != inputs_.end() && it->second != nullptr;
    }
    template <class T>
    const T& input(const std::string& slot) const {
        const BufferHandle* handle = checked(inputs_, slot, BufferTypeName<T>::value, "input");
        if (!handle->data)
            throw std::logic_error("input '" + slot + "' of '" + instance_ + "' is streamed: read it in consumeBatch");
        return *static_cast<const T*>(handle->data.get());
    }
    // An in-out slot: the buffer as the previous version left it, to update in place.
    template <class T>
    T& inout(const std::string& slot) {
        BufferHandle* handle = checked(outputs_, slot, BufferTypeName<T>::value, "in-out slot");
        if (!handle->data) throw std::logic_error("in-out slot '" + slot + "' of '" + instance_ + "' holds no buffer");
        return *static_cast<T*>(handle->data.get());
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
    // Demand-driven streams: emitBatch returns false once every reader of the
    // slot has said it wants no more (wantNoMoreBatches); the producer then stops
    // at this batch boundary. Readers decide on the batches in emission order,
    // so the batches made are the same for any thread count.
    bool streamed(const std::string& outputSlot) const;
    template <class T>
    bool emitBatch(const std::string& slot, std::shared_ptr<const T> batch) {
        checked(outputs_, slot, BufferTypeName<T>::value, "output");
        if (!streamed(slot)) throw std::logic_error("output '" + slot + "' of '" + instance_ + "' is not streamed");
        const std::size_t bytes = batch->bytes();
        return emitErased(slot, std::const_pointer_cast<void>(std::static_pointer_cast<const void>(std::move(batch))), bytes);
    }
    // A reader, inside consumeBatch: no more batches of this input are needed.
    void wantNoMoreBatches(const std::string& inputSlot) { satisfied_.push_back(inputSlot); }
    bool wantsMoreBatches(const std::string& inputSlot) const {
        return std::find(satisfied_.begin(), satisfied_.end(), inputSlot) == satisfied_.end();
    }
    // Returns whether any reader still wants batches of the slot.
    using BatchSink = std::function<bool(const std::string& slot, std::shared_ptr<void> batch, std::size_t bytes)>;
    void setBatchSink(std::vector<std::string> streamedOutputs, BatchSink sink) {
        streamedOutputs_ = std::move(streamedOutputs);
        batchSink_ = std::move(sink);
    }

    // Progress in [0, 1] of a long pass, shown as a bar on a terminal.
    void reportProgress(double fraction) const;
    void setProgressSink(std::function<void(const std::string&, double)> sink) { progress_ = std::move(sink); }

    // Interrupts (engine/core/interrupt.h). A pass that works in units (sample
    // passes, photon batches) calls completedUnit() after each and, before
    // starting the next, stops if stopRequested(); it then records what it
    // kept with keptPartial ("pt: 37 of 256 samples per pixel"), and its
    // outputs must be a correct estimate from the units done (normalised by
    // what was actually done). Passes inside a repeat block never see a stop
    // request: the block stops after the running iteration instead.
    bool stopRequested() const;
    void completedUnit() const;
    void keptPartial(std::string what) { partial_ = std::move(what); }
    const std::string& partial() const { return partial_; }
    void setStoppable(bool stoppable) { stoppable_ = stoppable; }

    // Raises a condition the pass declared in PassSpec::signals (pass thread only).
    void signal(const std::string& name);
    bool signalled(const std::string& name) const {
        return std::find(signals_.begin(), signals_.end(), name) != signals_.end();
    }
    void setDeclaredSignals(std::vector<std::string> declared) { declaredSignals_ = std::move(declared); }

private:
    static BufferHandle* checked(const std::map<std::string, BufferHandle*>& slots, const std::string& slot,
                                 const char* type, const char* kind);
    bool emitErased(const std::string& slot, std::shared_ptr<void> batch, std::size_t bytes);
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
    int iteration_ = -1;
    std::vector<std::string> satisfied_;
    std::vector<std::string> signals_, declaredSignals_;
    bool stoppable_ = true;
    std::string partial_;
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
    // Checks before any work (scene, parameters); empty = nothing to check.
    std::function<void(const PreflightContext&)> preflight;
    // The bytes of the buffers the pass will allocate, from its parameters, the
    // film and the scene (engine/core/memory.h); empty = nothing worth counting.
    std::function<MemoryEstimate(const PreflightContext&)> memory;
};

// A pass instance in a pipeline: buffers are bound by name; by default a slot
// binds to the buffer of the same name. In-out slots bind through inputBindings.
struct PipelineNode {
    std::string instance;  // unique within the pipeline; parameters live under [passes.<instance>]
    std::string pass;      // registered pass name
    std::map<std::string, std::string> inputBindings;   // slot -> buffer
    std::map<std::string, std::string> outputBindings;  // slot -> buffer
    int sourceLine = 0;    // where a job file defined it, for messages
};

// A block of passes run `count` times (unrolled into the plan before it is
// validated). Inside iteration i a buffer the block produces is a version of
// its own; `carry` names what iteration i+1 reads of iteration i: { read name =
// produced name }. Iteration 0 reads the version from before the block, if any.
struct RepeatBlock {
    std::string name;
    int count = 1;
    std::map<std::string, std::string> carry;
    std::string until;      // "instance.signal": stop after the iteration that raises it
    double seconds = 0.0;   // > 0: stop after the first iteration that ends past this budget
    std::vector<PipelineNode> nodes;
    std::size_t position = 0;  // the block comes before Pipeline::nodes[position]
    int sourceLine = 0;
};

struct Pipeline {
    std::string name;
    std::string doc;
    std::vector<PipelineNode> nodes;
    std::vector<std::string> results;  // buffers the run must produce (the images written out)
    bool streamBatches = true;  // stream buffers whose producer and readers allow it (job key stream_batches)
    std::vector<RepeatBlock> blocks;
    std::string file;  // where it was defined (built-in pipelines: passes/pipelines/NAME.toml)
};

// The passes and built-in pipelines a program offers. The engine never looks
// them up itself: the program installs its registry (fluxgraph's main, the
// tests) and passes the engine functions use the installed one by default.
struct Registry {
    std::vector<PassRegistration> passes;
    std::vector<Pipeline> pipelines;
    const PassRegistration* findPass(const std::string& name) const;
    const Pipeline* findPipeline(const std::string& name) const;
};
void installRegistry(const Registry* registry);
// Throws std::logic_error when none is installed.
const Registry& installedRegistry();

}  // namespace fg
