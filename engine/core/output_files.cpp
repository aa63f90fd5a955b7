// Checked, all-or-nothing output files; see output_files.h.
//
// Why checked write(2) calls rather than re-reading the file afterwards: a
// re-read proves the bytes reached the page cache, which the successful
// write(2) calls already prove; what it cannot see is a write-back failure,
// and fsync(2) is the call that reports that. So every write, the fsync and
// the close are checked, and nothing else is needed.
#include "engine/core/output_files.h"

#include "engine/core/error.h"

#include <fcntl.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <streambuf>
#include <system_error>

namespace fg {

namespace fs = std::filesystem;

namespace {

// Writes all of `size` bytes; returns 0 or the errno of the failure.
int writeAll(int fd, const char* data, std::size_t size) {
    while (size > 0) {
        const ssize_t written = ::write(fd, data, size);
        if (written < 0) {
            if (errno == EINTR) continue;
            return errno;
        }
        if (written == 0) return EIO;  // no progress and no reason: do not spin
        data += written;
        size -= static_cast<std::size_t>(written);
    }
    return 0;
}

// A stream buffer over a file descriptor that remembers the first failed write.
class CheckedFileBuffer : public std::streambuf {
public:
    explicit CheckedFileBuffer(int fd) : fd_(fd) { setp(buffer_.data(), buffer_.data() + buffer_.size()); }
    int error() const { return error_; }

protected:
    int_type overflow(int_type ch) override {
        if (!drain()) return traits_type::eof();
        if (!traits_type::eq_int_type(ch, traits_type::eof())) {
            *pptr() = traits_type::to_char_type(ch);
            pbump(1);
        }
        return traits_type::not_eof(ch);
    }
    std::streamsize xsputn(const char* data, std::streamsize size) override {
        // Large blocks (image and buffer payloads) skip the copy.
        if (size < static_cast<std::streamsize>(buffer_.size())) return std::streambuf::xsputn(data, size);
        if (!drain()) return 0;
        error_ = writeAll(fd_, data, static_cast<std::size_t>(size));
        return error_ ? 0 : size;
    }
    int sync() override { return drain() ? 0 : -1; }

private:
    bool drain() {
        if (error_) return false;
        error_ = writeAll(fd_, pbase(), static_cast<std::size_t>(pptr() - pbase()));
        setp(buffer_.data(), buffer_.data() + buffer_.size());
        return error_ == 0;
    }

    int fd_;
    int error_ = 0;
    std::array<char, 1 << 16> buffer_{};
};

[[noreturn]] void failWrite(const std::string& finalPath, const std::string& temporaryPath, int error) {
    ::unlink(temporaryPath.c_str());
    throw InputError(finalPath, 0, "cannot write: " + std::generic_category().message(error));
}

}  // namespace

std::string temporaryPathFor(const std::string& path) {
    static std::atomic<unsigned long> counter{0};
    const fs::path target(path);
    std::string name = ".";
    name += target.stem().string();
    name += ".tmp-";
    name += std::to_string(::getpid());
    name += '-';
    name += std::to_string(counter.fetch_add(1));
    name += target.extension().string();
    return (target.parent_path() / name).string();
}

void writeFileChecked(const std::string& finalPath, const std::string& temporaryPath,
                      const std::function<void(std::ostream&)>& fill) {
    const int fd = ::open(temporaryPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
    if (fd < 0) failWrite(finalPath, temporaryPath, errno);
    int error = 0;
    {
        CheckedFileBuffer buffer(fd);
        std::ostream out(&buffer);
        try {
            fill(out);
        } catch (...) {
            ::close(fd);
            ::unlink(temporaryPath.c_str());
            throw;
        }
        out.flush();
        error = buffer.error();
        if (!error && !out) error = EIO;  // the stream failed without a failed write
    }
    if (!error && ::fsync(fd) != 0) error = errno;
    if (::close(fd) != 0 && !error) error = errno;
    if (error) failWrite(finalPath, temporaryPath, error);
}

void writeFileChecked(const std::string& finalPath, const std::string& temporaryPath, std::string_view bytes) {
    writeFileChecked(finalPath, temporaryPath,
                     [&](std::ostream& out) { out.write(bytes.data(), static_cast<std::streamsize>(bytes.size())); });
}

void atomicRename(const std::string& from, const std::string& to) {
    std::error_code error;
    fs::rename(from, to, error);
    if (error) throw InputError(to, 0, "cannot write: " + error.message());
}

OutputCommit::~OutputCommit() {
    if (committed_) return;
    std::error_code ignored;
    for (const Staged& s : staged_) {
        fs::remove(s.temporaryPath, ignored);
        unregisterCleanupPath(s.temporaryPath);
    }
    // Deepest first; a directory something else has written into stays.
    for (auto it = createdDirectories_.rbegin(); it != createdDirectories_.rend(); ++it) {
        fs::remove(*it, ignored);
        unregisterCleanupPath(it->string());
    }
}

void OutputCommit::createDirectories(const std::string& directory) {
    std::vector<fs::path> missing;
    std::error_code ec;
    for (fs::path p = fs::path(directory).lexically_normal(); !p.empty() && !fs::exists(p, ec);
         p = p.parent_path()) {
        missing.push_back(p);
        if (p == p.parent_path()) break;
    }
    for (auto it = missing.rbegin(); it != missing.rend(); ++it) {
        const bool created = fs::create_directory(*it, ec);
        if (ec) break;
        if (created) {
            registerCreatedDirectory(it->string());
            const std::lock_guard lock(mutex_);
            createdDirectories_.push_back(*it);
        }
    }
    if (ec || !fs::is_directory(directory, ec)) throw InputError(directory + ": cannot create output directory");
}

std::string OutputCommit::stage(const std::string& finalPath) {
    std::string temporary = temporaryPathFor(finalPath);
    // Registered before anything is written, so a signal never finds an unlisted temporary.
    registerTemporaryFile(temporary);
    const std::lock_guard lock(mutex_);
    staged_.push_back({finalPath, temporary});
    return temporary;
}

void OutputCommit::commit() {
    const std::lock_guard lock(mutex_);
    pauseForTest("write");
    // A quitting signal waits for the renames (see interrupt.h).
    enterCommitSection();
    struct LeaveCommit {
        ~LeaveCommit() { leaveCommitSection(); }
    } leaveCommit;
    std::error_code ec;
    // A directory under a final name is the likely failure; finding it first
    // means no rename has to be undone.
    for (const Staged& s : staged_)
        if (fs::is_directory(s.finalPath, ec)) throw InputError(s.finalPath, 0, "cannot write: is a directory");
    for (std::size_t i = 0; i < staged_.size(); ++i) {
        fs::rename(staged_[i].temporaryPath, staged_[i].finalPath, ec);
        if (ec) {
            rollBack(i);
            throw InputError(staged_[i].finalPath, 0, "cannot write: " + ec.message());
        }
    }
    committed_ = true;
    for (const Staged& s : staged_) unregisterCleanupPath(s.temporaryPath);
    for (const fs::path& directory : createdDirectories_) unregisterCleanupPath(directory.string());
}

void OutputCommit::rollBack(std::size_t renamedCount) noexcept {
    std::error_code ignored;
    for (std::size_t i = 0; i < renamedCount; ++i) {
        fs::remove(staged_[i].finalPath, ignored);
        unregisterCleanupPath(staged_[i].temporaryPath);
    }
    // The remaining temporaries and created directories go in the destructor.
    staged_.erase(staged_.begin(), staged_.begin() + static_cast<std::ptrdiff_t>(renamedCount));
}

}  // namespace fg
