// A deliberately small tmpfs, for tests of what a full disk does to a writer.
// Mounting needs root (or CAP_SYS_ADMIN); where the mount is refused the test
// skips and says so.
#pragma once

#include <gtest/gtest.h>

#include <sys/mount.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <string>

namespace fg::test {

class SmallFilesystem {
public:
    // Mounts a tmpfs of `sizeBytes` (rounded up to pages) on `directory`, creating it.
    SmallFilesystem(const std::filesystem::path& directory, std::size_t sizeBytes) : directory_(directory) {
        std::filesystem::create_directories(directory_);
        const std::string options = "size=" + std::to_string(sizeBytes);
        if (::mount("tmpfs", directory_.c_str(), "tmpfs", 0, options.c_str()) == 0) {
            mounted_ = true;
        } else {
            refusal_ = std::string("mount -t tmpfs refused: ") + std::strerror(errno);
        }
    }
    SmallFilesystem(const SmallFilesystem&) = delete;
    SmallFilesystem& operator=(const SmallFilesystem&) = delete;
    ~SmallFilesystem() {
        if (mounted_) ::umount2(directory_.c_str(), MNT_DETACH);
    }

    bool mounted() const { return mounted_; }
    // Why there is no small filesystem, for GTEST_SKIP.
    const std::string& refusal() const { return refusal_; }

private:
    std::filesystem::path directory_;
    bool mounted_ = false;
    std::string refusal_;
};

}  // namespace fg::test

// Skips the calling test, naming the refused mount, unless `fs` is mounted.
#define FG_SKIP_UNLESS_MOUNTED(fs) \
    if (!(fs).mounted()) GTEST_SKIP() << (fs).refusal() << "; a full disk cannot be simulated here"
