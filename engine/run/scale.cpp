// Thread-scaling measurements (see scale.h): repeated renders of one job at
// several thread counts, reduced to medians and an Amdahl fit, plus a byte
// comparison of every run's result images with the first run's.
#include "engine/run/scale.h"

#include "engine/core/error.h"
#include "engine/core/render.h"
#include "engine/image/film.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <iomanip>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <thread>

namespace fg::run {

namespace {

// A run's result images as resolved pixels, by result name.
using ResolvedImages = std::map<std::string, std::vector<Rgb>>;

ResolvedImages resolvedImages(const RunResult& run) {
    ResolvedImages images;
    for (const auto& [name, handle] : run.results)
        if (handle.type == "Film") images[name] = static_cast<const Film*>(handle.data.get())->resolve();
    return images;
}

bool sameBytes(const std::vector<Rgb>& a, const std::vector<Rgb>& b) {
    return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(Rgb)) == 0);
}

// Wall seconds per row of the pass table: plain instances, and each repeat
// block's passes summed over iterations (one row instead of one per iteration).
std::vector<std::pair<std::string, double>> passWallSeconds(const RunResult& run) {
    std::vector<std::pair<std::string, double>> rows;
    for (const PassStats& s : run.stats)
        if (s.block.empty()) rows.emplace_back(s.instance, s.wallSeconds);
    for (const PassStats& s : blockPassSums(run.stats)) rows.emplace_back(s.instance, s.wallSeconds);
    return rows;
}

std::string csvField(const std::string& text) {
    if (text.find_first_of(",\"\n") == std::string::npos) return text;
    std::string quoted = "\"";
    for (char c : text) quoted += c == '"' ? std::string("\"\"") : std::string(1, c);
    return quoted + "\"";
}

std::string formatNumber(double value, int precision) {
    if (std::isnan(value)) return "nan";
    std::ostringstream out;
    out << std::fixed << std::setprecision(precision) << value;
    return out.str();
}

}  // namespace

std::vector<int> parseThreadList(const std::string& text) {
    const auto fail = [&](const std::string& why) -> std::vector<int> {
        throw InputError("--threads '" + text + "': " + why);
    };
    if (text.empty()) return fail("expected a comma-separated list of thread counts, e.g. 1,2,4");
    std::set<int> counts;
    std::size_t start = 0;
    while (true) {
        const std::size_t comma = text.find(',', start);
        const std::string item = text.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
        if (item.empty()) return fail("empty item; expected a comma-separated list of thread counts, e.g. 1,2,4");
        long long value = 0;
        const auto [next, error] = std::from_chars(item.data(), item.data() + item.size(), value);
        if (error == std::errc::result_out_of_range) return fail("'" + item + "' is too large");
        if (error != std::errc() || next != item.data() + item.size()) return fail("'" + item + "' is not an integer");
        if (value < 1) return fail("'" + item + "': thread counts must be at least 1");
        if (value > kMaxScaleThreads) return fail("'" + item + "': at most " + std::to_string(kMaxScaleThreads));
        counts.insert(static_cast<int>(value));
        if (comma == std::string::npos) break;
        start = comma + 1;
    }
    return {counts.begin(), counts.end()};
}

double fitSerialFraction(const std::vector<int>& threads, const std::vector<double>& seconds, double oneThreadSeconds) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    if (!(oneThreadSeconds > 0.0) || threads.size() != seconds.size()) return nan;
    double xy = 0.0, xx = 0.0;
    for (std::size_t i = 0; i < threads.size(); ++i) {
        const double inverse = 1.0 / threads[i];
        const double x = oneThreadSeconds * (1.0 - inverse);
        const double y = seconds[i] - oneThreadSeconds * inverse;
        xy += x * y;
        xx += x * x;
    }
    if (xx <= 0.0) return nan;
    return std::clamp(xy / xx, 0.0, 1.0);
}

double median(std::vector<double> values) {
    if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
    const std::size_t middle = values.size() / 2;
    std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(middle), values.end());
    const double upper = values[middle];
    if (values.size() % 2 == 1) return upper;
    const double lower = *std::max_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(middle));
    return 0.5 * (lower + upper);
}

void summarize(ScaleSeries& series, int hardwareThreads) {
    std::vector<int> threads;
    std::vector<double> medians;
    for (ThreadTiming& t : series.timings) {
        t.median = median(t.seconds);
        t.min = t.seconds.empty() ? 0.0 : *std::min_element(t.seconds.begin(), t.seconds.end());
        t.max = t.seconds.empty() ? 0.0 : *std::max_element(t.seconds.begin(), t.seconds.end());
        t.oversubscribed = hardwareThreads > 0 && t.threads > hardwareThreads;
        threads.push_back(t.threads);
        medians.push_back(t.median);
    }
    const double oneThread = !series.timings.empty() && series.timings.front().threads == 1
                                 ? series.timings.front().median
                                 : std::numeric_limits<double>::quiet_NaN();
    for (ThreadTiming& t : series.timings) {
        t.speedup = t.median > 0.0 ? oneThread / t.median : std::numeric_limits<double>::quiet_NaN();
        t.efficiency = t.speedup / t.threads;
    }
    series.serialFraction = fitSerialFraction(threads, medians, oneThread);
}

ScaleReport measureScaling(const std::string& jobPath, const JobOverrides& overrides, const ScaleSettings& settings) {
    if (settings.repeat < 1) throw InputError("--repeat " + std::to_string(settings.repeat) + ": must be at least 1");
    if (settings.threads.empty()) throw InputError("--threads: no thread counts given");
    for (int n : settings.threads)
        if (n < 1) throw InputError("--threads: " + std::to_string(n) + ": thread counts must be at least 1");

    ScaleReport report;
    report.jobPath = jobPath;
    report.repeat = settings.repeat;
    report.hardwareThreads = static_cast<int>(std::thread::hardware_concurrency());
    std::set<int> threads(settings.threads.begin(), settings.threads.end());
    report.baselineAdded = threads.insert(1).second;
    report.threads.assign(threads.begin(), threads.end());

    // Loaded (and so checked) before any render: a bad --set at 16 threads
    // should not surface after the 1-thread runs.
    std::vector<Job> jobs;
    for (int n : report.threads) {
        JobOverrides atN = overrides;
        atN.threads = n;
        jobs.push_back(loadJob(jobPath, atN));
    }

    // seconds[row name][thread index] -> one value per repetition
    std::map<std::string, std::vector<std::vector<double>>> passSeconds;
    std::vector<std::string> passOrder;
    std::vector<std::vector<double>> pipelineSeconds(report.threads.size());
    ResolvedImages reference;
    bool haveReference = false;

    for (int repetition = 1; repetition <= settings.repeat; ++repetition) {
        for (std::size_t i = 0; i < report.threads.size(); ++i) {
            if (settings.progress) settings.progress(report.threads[i], repetition, settings.repeat);
            const RenderOutcome outcome = renderJob(jobs[i], RenderOptions{});
            pipelineSeconds[i].push_back(outcome.run.wallSeconds);
            for (const auto& [name, seconds] : passWallSeconds(outcome.run)) {
                auto [it, added] = passSeconds.try_emplace(name, report.threads.size());
                if (added) passOrder.push_back(name);
                it->second[i].push_back(seconds);
            }
            ResolvedImages images = resolvedImages(outcome.run);
            if (!haveReference) {
                reference = std::move(images);
                haveReference = true;
                report.imagesCompared = static_cast<int>(reference.size());
            } else {
                bool sameSet = images.size() == reference.size();
                for (const auto& [name, pixels] : reference) {
                    const auto it = images.find(name);
                    if (it == images.end()) {
                        sameSet = false;
                        continue;
                    }
                    if (!sameBytes(pixels, it->second))
                        report.mismatches.push_back({report.threads[i], repetition, name});
                }
                if (!sameSet) report.mismatches.push_back({report.threads[i], repetition, ""});
            }
            if (repetition == settings.repeat && i + 1 == report.threads.size()) report.files = outcome.files;
        }
    }

    const auto series = [&](const std::string& name, const std::vector<std::vector<double>>& seconds) {
        ScaleSeries s;
        s.name = name;
        for (std::size_t i = 0; i < report.threads.size(); ++i) {
            if (seconds[i].empty()) continue;  // a pass some runs skipped (early exit of a repeat block)
            ThreadTiming t;
            t.threads = report.threads[i];
            t.seconds = seconds[i];
            s.timings.push_back(std::move(t));
        }
        summarize(s, report.hardwareThreads);
        return s;
    };
    for (const std::string& name : passOrder) report.passes.push_back(series(name, passSeconds.at(name)));
    report.pipeline = series("pipeline", pipelineSeconds);
    return report;
}

std::string formatScaleTable(const ScaleReport& report) {
    std::ostringstream out;
    out << report.jobPath << ": median of " << report.repeat << " run" << (report.repeat == 1 ? "" : "s")
        << " per thread count; " << report.hardwareThreads << " hardware threads\n";
    if (report.baselineAdded) out << "1 thread was not asked for; it was run anyway as the baseline T(1) of the speed-up\n";
    std::size_t width = std::string("pipeline").size() + 2;
    for (const ScaleSeries& s : report.passes) width = std::max(width, s.name.size() + 2);
    const int w = static_cast<int>(width);
    out << std::left << std::setw(w) << "pass" << std::right << std::setw(8) << "threads" << std::setw(10) << "wall s"
        << std::setw(10) << "speed-up" << std::setw(12) << "efficiency" << std::setw(10) << "serial f" << "\n";
    const auto rows = [&](const ScaleSeries& s) {
        bool first = true;
        for (const ThreadTiming& t : s.timings) {
            std::ostringstream line;
            line << std::left << std::setw(w) << (first ? s.name : "") << std::right << std::setw(8) << t.threads
                 << std::setw(10) << formatNumber(t.median, 3) << std::setw(10) << formatNumber(t.speedup, 2)
                 << std::setw(12) << formatNumber(t.efficiency, 2) << std::setw(10)
                 << (first ? formatNumber(s.serialFraction, 3) : "");
            if (t.oversubscribed) line << "  oversubscribed";
            std::string text = line.str();
            text.erase(text.find_last_not_of(' ') + 1);
            out << text << "\n";
            first = false;
        }
    };
    for (const ScaleSeries& s : report.passes) rows(s);
    rows(report.pipeline);

    std::string counts;
    for (int n : report.threads) counts += (counts.empty() ? "" : ", ") + std::to_string(n);
    if (report.mismatches.empty()) {
        out << "images: bit-identical at " << counts << " threads, every repetition (" << report.imagesCompared
            << " result image" << (report.imagesCompared == 1 ? "" : "s") << " compared)\n";
    } else {
        std::set<int> differing;
        for (const ImageMismatch& m : report.mismatches) differing.insert(m.threads);
        std::string list;
        for (int n : differing) list += (list.empty() ? "" : ", ") + std::to_string(n);
        out << "IMAGES DIFFER from the 1-thread run at " << list << " threads:";
        for (const ImageMismatch& m : report.mismatches)
            out << " " << (m.result.empty() ? "(results)" : m.result) << "@" << m.threads << "t#" << m.repetition;
        out << "\n";
    }
    return out.str();
}

std::string scaleCsv(const ScaleReport& report) {
    std::ostringstream out;
    out << "pass,threads,median_s,min_s,max_s,speedup,efficiency,serial_fraction,oversubscribed\n";
    const auto rows = [&](const ScaleSeries& s) {
        for (const ThreadTiming& t : s.timings)
            out << csvField(s.name) << ',' << t.threads << ',' << formatNumber(t.median, 9) << ','
                << formatNumber(t.min, 9) << ',' << formatNumber(t.max, 9) << ',' << formatNumber(t.speedup, 6) << ','
                << formatNumber(t.efficiency, 6) << ',' << formatNumber(s.serialFraction, 6) << ','
                << (t.oversubscribed ? 1 : 0) << '\n';
    };
    for (const ScaleSeries& s : report.passes) rows(s);
    rows(report.pipeline);
    return out.str();
}

}  // namespace fg::run
