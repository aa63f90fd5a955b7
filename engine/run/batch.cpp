// The batch runner: renders a plan's runs one after another in this process,
// sharing loaded scenes between runs, and keeps the results table whole and
// current at every moment so that an interrupted batch can be read and resumed.
#include "engine/run/batch.h"

#include "engine/accel/ray_query.h"
#include "engine/core/error.h"
#include "engine/core/pass.h"
#include "engine/core/render.h"
#include "engine/image/image_compare.h"
#include "engine/image/image_io.h"
#include "engine/scene/scene_loader.h"
#include "jobs/parallel.h"

#include <fcntl.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <map>
#include <memory>
#include <sstream>

namespace fg {

namespace {

namespace fs = std::filesystem;

std::string oneLine(std::string message) {
    for (char& c : message)
        if (c == '\n' || c == '\r') c = ' ';
    while (!message.empty() && message.back() == ' ') message.pop_back();
    return message;
}

std::string jsonString(const std::string& s) { return "\"" + jsonEscape(s) + "\""; }

std::string number(double value) {
    if (std::isnan(value)) return "nan";
    if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
    char buffer[64];
    std::snprintf(buffer, sizeof buffer, "%.9g", value);
    return buffer;
}

// JSON has no nan or inf.
std::string jsonNumber(double value) { return std::isfinite(value) ? number(value) : "null"; }

std::string csvField(const std::string& text) {
    if (text.find_first_of(",\"\n\r") == std::string::npos) return text;
    std::string out = "\"";
    for (char c : text) out += c == '"' ? std::string("\"\"") : std::string(1, c);
    return out + "\"";
}

std::string utcTimestamp() {
    const std::time_t now = std::time(nullptr);
    std::tm parts{};
    ::gmtime_r(&now, &parts);
    char buffer[32];
    std::strftime(buffer, sizeof buffer, "%Y-%m-%dT%H:%M:%SZ", &parts);
    return buffer;
}

long peakRssKib() {
    rusage usage{};
    ::getrusage(RUSAGE_SELF, &usage);
    return usage.ru_maxrss;  // KiB on Linux
}

// One write() per line: readers (and a batch killed mid-row) never see half a row.
void appendLine(const std::string& path, const std::string& line) {
    const int fd = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0) throw InputError(path + ": cannot open for appending");
    std::size_t written = 0;
    while (written < line.size()) {
        const ssize_t n = ::write(fd, line.data() + written, line.size() - written);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) {
            ::close(fd);
            throw InputError(path + ": cannot append a row");
        }
        written += static_cast<std::size_t>(n);
    }
    ::close(fd);
}

struct BatchRow {
    std::string started;
    const BatchRun* run = nullptr;
    std::string seed;
    std::string threads;
    std::string status;
    std::string error;
    std::vector<std::string> exrFiles;
    double wallSeconds = 0.0;
    std::optional<RenderOutcome> outcome;
    double sceneSeconds = 0.0;
    double accelSeconds = 0.0;
    std::optional<ImageMetrics> metrics;
};

std::string joinedSets(const BatchRun& run) {
    std::string text;
    for (const std::string& s : run.sets) text += (text.empty() ? "" : " ") + s;
    return text;
}

struct PassTotals {
    double wall = 0.0, cpu = 0.0;
    std::int64_t items = 0;
    std::size_t bytes = 0;
};

PassTotals totals(const BatchRow& row) {
    PassTotals t;
    if (!row.outcome) return t;
    for (const PassStats& s : row.outcome->run.stats) {
        t.wall += s.wallSeconds;
        t.cpu += s.cpuSeconds;
        t.items += s.items;
        t.bytes += s.outputBytes;
    }
    return t;
}

std::string csvLine(const BatchRow& row) {
    const PassTotals t = totals(row);
    const bool ran = row.outcome.has_value();
    const auto metric = [&](double ImageMetrics::*field) { return row.metrics ? number((*row.metrics).*field) : ""; };
    const std::vector<std::string> fields = {
        row.started, row.run->name, row.run->jobPath, joinedSets(*row.run), row.seed, row.threads, row.status,
        row.error, row.exrFiles.empty() ? "" : row.exrFiles.front(), number(row.wallSeconds),
        ran ? number(row.sceneSeconds) : "", ran ? number(row.accelSeconds) : "",
        ran ? number(row.outcome->run.wallSeconds) : "", ran ? number(t.wall) : "", ran ? number(t.cpu) : "",
        ran ? std::to_string(t.items) : "", ran ? std::to_string(t.bytes) : "", std::to_string(peakRssKib()),
        row.run->referencePath, metric(&ImageMetrics::rmse), metric(&ImageMetrics::relmse),
        metric(&ImageMetrics::mae), metric(&ImageMetrics::ssim), metric(&ImageMetrics::psnr)};
    std::string line;
    for (std::size_t i = 0; i < fields.size(); ++i) line += (i ? "," : "") + csvField(fields[i]);
    return line + "\n";
}

std::string jsonLine(const BatchRow& row) {
    std::ostringstream out;
    out << "{\"batch_started\": " << jsonString(row.started) << ", \"run\": " << jsonString(row.run->name)
        << ", \"job\": " << jsonString(row.run->jobPath) << ", \"overrides\": [";
    for (std::size_t i = 0; i < row.run->sets.size(); ++i) out << (i ? ", " : "") << jsonString(row.run->sets[i]);
    out << "], \"seed\": " << (row.seed.empty() ? "null" : row.seed)
        << ", \"threads\": " << (row.threads.empty() ? "null" : row.threads) << ", \"status\": " << jsonString(row.status)
        << ", \"error\": " << jsonString(row.error) << ", \"exr\": [";
    for (std::size_t i = 0; i < row.exrFiles.size(); ++i) out << (i ? ", " : "") << jsonString(row.exrFiles[i]);
    out << "], \"wall_seconds\": " << jsonNumber(row.wallSeconds);
    if (row.outcome) {
        const PassTotals t = totals(row);
        out << ", \"scene_seconds\": " << jsonNumber(row.sceneSeconds)
            << ", \"accel_seconds\": " << jsonNumber(row.accelSeconds)
            << ", \"passes_seconds\": " << jsonNumber(row.outcome->run.wallSeconds)
            << ", \"passes_wall_seconds\": " << jsonNumber(t.wall) << ", \"passes_cpu_seconds\": " << jsonNumber(t.cpu)
            << ", \"items\": " << t.items << ", \"output_bytes\": " << t.bytes << ", \"passes\": [";
        const auto& stats = row.outcome->run.stats;
        for (std::size_t i = 0; i < stats.size(); ++i) {
            const PassStats& s = stats[i];
            out << (i ? ", " : "") << "{\"instance\": " << jsonString(s.instance) << ", \"pass\": " << jsonString(s.pass)
                << ", \"wall_seconds\": " << jsonNumber(s.wallSeconds) << ", \"cpu_seconds\": " << jsonNumber(s.cpuSeconds)
                << ", \"items\": " << s.items << ", \"output_bytes\": " << s.outputBytes << ", \"counters\": {";
            bool first = true;
            for (const auto& [name, value] : s.counters) {
                out << (first ? "" : ", ") << jsonString(name) << ": " << value;
                first = false;
            }
            out << "}}";
        }
        out << "]";
    }
    out << ", \"peak_rss_kib\": " << peakRssKib() << ", \"reference\": " << jsonString(row.run->referencePath);
    if (row.metrics)
        out << ", \"rmse\": " << jsonNumber(row.metrics->rmse) << ", \"relmse\": " << jsonNumber(row.metrics->relmse)
            << ", \"mae\": " << jsonNumber(row.metrics->mae) << ", \"ssim\": " << jsonNumber(row.metrics->ssim)
            << ", \"psnr\": " << jsonNumber(row.metrics->psnr);
    out << "}\n";
    return out.str();
}

// The EXR files a job writes: one per Film result.
std::vector<std::string> exrFilesOf(const Job& job) {
    const ExecutionPlan plan =
        ExecutionPlan::build(job.pipeline, job.params, job.path, installedRegistry().passes, job.bufferFiles);
    std::vector<std::string> files;
    for (const std::string& result : job.pipeline.results) {
        if (plan.bufferTypeOf(plan.finalVersion(result)) != "Film") continue;
        const std::string stem = job.pipeline.results.size() == 1 ? job.output.name : job.output.name + "-" + result;
        files.push_back((fs::path(job.output.directory) / (stem + ".exr")).string());
    }
    return files;
}

std::string metadataValue(const Metadata& metadata, const std::string& key) {
    for (const auto& [k, v] : metadata)
        if (k == key) return v;
    return {};
}

// Every image exists and was rendered from this job text with these overrides.
bool upToDate(const Job& job, const std::vector<std::string>& exrFiles) {
    if (exrFiles.empty()) return false;
    std::string overrides;
    for (const std::string& o : job.overrides) overrides += (overrides.empty() ? "" : " ") + o;
    for (const std::string& file : exrFiles) {
        std::error_code ec;
        if (!fs::is_regular_file(file, ec)) return false;
        Metadata metadata;
        try {
            readExr(file, &metadata);
        } catch (const std::exception&) {
            return false;
        }
        if (metadataValue(metadata, "job") != job.text || metadataValue(metadata, "overrides") != overrides) return false;
    }
    return true;
}

// Scenes and their Embree scenes, kept while runs still need them.
class SceneCache {
public:
    struct Entry {
        Scene scene;
        std::unique_ptr<RayQuery> rays;
        int usesLeft = 0;
    };

    static std::string keyOf(const Job& job) {
        std::string key = job.scenePath;
        for (const auto& [name, value] : job.sceneDefines) key += '\n' + name + '=' + value;
        return key;
    }
    void expectUse(const Job& job) { ++uses_[keyOf(job)]; }

    // The entry for the job's scene, loaded and built on first use; `loaded`
    // receives the time this call spent loading and building.
    Entry& acquire(const Job& job, double& sceneSeconds, double& accelSeconds) {
        sceneSeconds = accelSeconds = 0.0;
        const std::string key = keyOf(job);
        auto it = entries_.find(key);
        if (it == entries_.end()) {
            const std::int64_t t0 = jobs::wallNanos();
            auto entry = std::make_unique<Entry>(Entry{loadScene(job.scenePath, job.sceneDefines), nullptr, uses_[key]});
            const std::int64_t t1 = jobs::wallNanos();
            {
                const jobs::ThreadLimit threadLimit(job.threads);
                entry->rays = std::make_unique<RayQuery>(entry->scene);
            }
            sceneSeconds = 1e-9 * static_cast<double>(t1 - t0);
            accelSeconds = 1e-9 * static_cast<double>(jobs::wallNanos() - t1);
            it = entries_.emplace(key, std::move(entry)).first;
        }
        return *it->second;
    }
    // A run is done with its scene (rendered, skipped or failed).
    void release(const Job& job) {
        const std::string key = keyOf(job);
        if (--uses_[key] > 0) return;
        entries_.erase(key);
    }

private:
    std::map<std::string, int> uses_;
    std::map<std::string, std::unique_ptr<Entry>> entries_;
};

class ProgressLine {
public:
    explicit ProgressLine(bool enabled, std::size_t total) : enabled_(enabled), total_(total) {}
    void update(std::size_t done) {
        if (!enabled_) return;
        const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
        const double remaining = done > 0 ? elapsed / static_cast<double>(done) * static_cast<double>(total_ - done) : 0.0;
        std::fprintf(stderr, "\rbatch: %zu/%zu runs, %.1f s elapsed, ~%.1f s left   ", done, total_, elapsed, remaining);
        std::fflush(stderr);
        shown_ = true;
    }
    void finish() {
        if (shown_) std::fputc('\n', stderr);
    }

private:
    bool enabled_;
    std::size_t total_;
    bool shown_ = false;
    std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

}  // namespace

std::string batchTimestamp() { return utcTimestamp(); }

const std::vector<std::string>& batchCsvColumns() {
    static const std::vector<std::string> columns = {
        "batch_started", "run", "job", "overrides", "seed", "threads", "status", "error", "exr", "wall_seconds",
        "scene_seconds", "accel_seconds", "passes_seconds", "passes_wall_seconds", "passes_cpu_seconds", "items",
        "output_bytes", "peak_rss_kib", "reference", "rmse", "relmse", "mae", "ssim", "psnr"};
    return columns;
}

std::string batchTableBase(const BatchPlan& plan, const BatchOptions& options) {
    if (!options.tableBase.empty()) return options.tableBase;
    return (fs::path(plan.outputDirectory) / fs::path(kBatchCsvName).stem()).string();
}

void prepareBatchOutput(const BatchPlan& plan, const std::string& tableBase) {
    std::error_code ec;
    fs::create_directories(plan.outputDirectory, ec);
    if (ec || !fs::is_directory(plan.outputDirectory, ec))
        throw InputError(plan.outputDirectory + ": cannot create the batch output directory");
    const std::string csv = (tableBase.empty() ? batchTableBase(plan, BatchOptions{}) : tableBase) + ".csv";
    if (fs::path(csv).has_parent_path()) {
        fs::create_directories(fs::path(csv).parent_path(), ec);
        if (ec) throw InputError(fs::path(csv).parent_path().string() + ": cannot create the table directory");
    }
    const std::uintmax_t csvSize = fs::file_size(csv, ec);
    if (!ec && csvSize > 0) return;
    std::string header;
    for (const std::string& column : batchCsvColumns()) header += (header.empty() ? "" : ",") + column;
    appendLine(csv, header + "\n");
}

BatchSummary runBatch(const BatchPlan& plan, const BatchOptions& options) {
    const std::vector<Job> jobs = validateBatchPlan(plan, options.threads);
    const std::string tableBase = batchTableBase(plan, options);
    if (options.writeHeader) prepareBatchOutput(plan, tableBase);
    const std::string csvPath = tableBase + ".csv";
    const std::string jsonlPath = tableBase + ".jsonl";
    const std::string started = options.startedAt.empty() ? utcTimestamp() : options.startedAt;

    std::vector<std::size_t> mine;
    const std::size_t first = std::min(options.firstRun, plan.runs.size());
    const std::size_t end = first + std::min(options.runCount, plan.runs.size() - first);
    for (std::size_t i = first; i < end; ++i)
        if (static_cast<int>((i - first) % static_cast<std::size_t>(options.workerCount)) == options.workerIndex)
            mine.push_back(i);
    SceneCache cache;
    for (std::size_t i : mine) cache.expectUse(jobs[i]);

    BatchSummary summary;
    ProgressLine progress(options.showProgress, mine.size());
    progress.update(0);
    for (std::size_t done = 0; done < mine.size(); ++done) {
        if (options.stopRequested && options.stopRequested->load()) {
            summary.interrupted = true;
            break;
        }
        const BatchRun& run = plan.runs[mine[done]];
        const Job& job = jobs[mine[done]];
        BatchRow row;
        row.started = started;
        row.run = &run;
        row.seed = std::to_string(job.seed);
        row.threads = std::to_string(job.threads > 0 ? job.threads : jobs::hardwareThreads());
        const auto t0 = std::chrono::steady_clock::now();
        try {
            row.exrFiles = exrFilesOf(job);
            if (!options.force && upToDate(job, row.exrFiles)) {
                row.status = "skipped";
            } else {
                auto& entry = cache.acquire(job, row.sceneSeconds, row.accelSeconds);
                RenderOptions renderOptions;
                renderOptions.commandLine = options.commandLine;
                row.outcome = renderJob(job, renderOptions, PreparedScene{entry.scene, *entry.rays});
                row.status = "ok";
            }
            if (!run.referencePath.empty() && !row.exrFiles.empty())
                row.metrics = compareImages(readImageLinear(row.exrFiles.front()), readImageLinear(run.referencePath));
        } catch (const std::exception& e) {
            row.status = "failed";
            row.error = oneLine(e.what());
        }
        cache.release(job);
        row.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        appendLine(csvPath, csvLine(row));
        appendLine(jsonlPath, jsonLine(row));
        if (row.status == "ok") ++summary.ok;
        else if (row.status == "skipped") ++summary.skipped;
        else ++summary.failed;
        progress.update(done + 1);
        if (row.status == "failed" && options.failFast) {
            summary.interrupted = done + 1 < mine.size();
            break;
        }
    }
    progress.finish();
    return summary;
}

}  // namespace fg
