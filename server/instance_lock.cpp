#include "instance_lock.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <chrono>
#include <random>

namespace fringe {

namespace fs = std::filesystem;

namespace {

bool valid_instance(const std::string& id) {
    if (id.empty() || id.size() > 64) return false;
    for (char c : id)
        if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_')) return false;
    return true;
}

std::string lock_dir(const std::string& data_dir) { return (fs::path(data_dir) / "locks").string(); }

// Opens (creating, mode 0600) and flocks path; -1 with errno EWOULDBLOCK if held elsewhere.
int open_locked(const std::string& path, int how) {
    const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600);
    if (fd < 0) return -1;
    if (::flock(fd, how | LOCK_NB) != 0) {
        const int e = errno;
        ::close(fd);
        errno = e;
        return -1;
    }
    return fd;
}

void write_owner(int fd, const std::string& id) {
    const std::string text = "pid " + std::to_string(getpid()) + " instance " + id + "\n";
    if (::ftruncate(fd, 0) == 0) {
        [[maybe_unused]] const auto n = ::pwrite(fd, text.data(), text.size(), 0);
    }
}

}  // namespace

std::string new_instance_id() {
    std::random_device rd;
    char hex[17];
    std::snprintf(hex, sizeof hex, "%08x%08x", static_cast<unsigned>(rd()), static_cast<unsigned>(rd()));
    return hex;
}

InstanceLock::~InstanceLock() {
    if (instance_fd_ >= 0) {
        // Unlinked while still held: a prober that opens it now creates a fresh, unlocked file
        // and takes the run for dead, which it is about to be anyway (rows are finished first).
        std::error_code ec;
        fs::remove(instance_path_, ec);
        ::close(instance_fd_);
    }
    if (service_fd_ >= 0) ::close(service_fd_);
}

void InstanceLock::acquire_service(const std::string& data_dir, const std::string& instance_id) {
    fs::create_directories(data_dir);
    const std::string path = (fs::path(data_dir) / "lock").string();
    const int fd = open_locked(path, LOCK_EX);
    if (fd < 0) {
        if (errno != EWOULDBLOCK) throw std::runtime_error("cannot lock " + path + ": " + std::strerror(errno));
        std::string owner;
        if (FILE* f = std::fopen(path.c_str(), "r")) {
            char line[256] = {};
            if (std::fgets(line, sizeof line, f)) owner = line;
            std::fclose(f);
        }
        while (!owner.empty() && (owner.back() == '\n' || owner.back() == '\r')) owner.pop_back();
        throw InstanceLockBusy("data folder " + fs::absolute(data_dir).lexically_normal().string() + " is in use by another fringe serve (" +
                               (owner.empty() ? "holder unknown" : owner) + "); one service per data folder: stop it or give another --data");
    }
    write_owner(fd, instance_id);
    service_fd_ = fd;
    acquire_instance(data_dir, instance_id);
}

void InstanceLock::acquire_instance(const std::string& data_dir, const std::string& instance_id) {
    if (!valid_instance(instance_id)) throw std::runtime_error("bad instance id '" + instance_id + "'");
    fs::create_directories(lock_dir(data_dir));
    ::chmod(lock_dir(data_dir).c_str(), 0700);
    instance_path_ = (fs::path(lock_dir(data_dir)) / (instance_id + ".lock")).string();
    const int fd = open_locked(instance_path_, LOCK_EX);
    if (fd < 0) throw std::runtime_error("cannot lock " + instance_path_ + ": " + std::strerror(errno));
    write_owner(fd, instance_id);
    instance_fd_ = fd;
    id_ = instance_id;
}

bool instance_alive(const std::string& data_dir, const std::string& instance_id) {
    if (!valid_instance(instance_id)) return false;
    const std::string path = (fs::path(lock_dir(data_dir)) / (instance_id + ".lock")).string();
    // Dead only when we know it: the file is gone, or we could lock it. Anything else (no
    // descriptors left, EACCES) says alive, since "dead" is written to the store for good.
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return errno != ENOENT;  // ENOENT: never made, or removed by its owner at exit
    const bool locked_by_us = ::flock(fd, LOCK_SH | LOCK_NB) == 0;
    const bool held = !locked_by_us;  // EWOULDBLOCK: someone holds it; other errors: cannot tell
    ::close(fd);  // drops our shared lock if we got it
    return held;
}

int remove_stale_instance_locks(const std::string& data_dir) {
    int n = 0;
    std::error_code ec;
    const auto now = fs::file_time_type::clock::now();
    for (const auto& e : fs::directory_iterator(lock_dir(data_dir), ec)) {
        const auto name = e.path().filename().string();
        if (e.path().extension() != ".lock") continue;
        std::error_code tec;
        const auto mtime = fs::last_write_time(e.path(), tec);
        if (tec || now - mtime < std::chrono::minutes(1)) continue;
        if (instance_alive(data_dir, e.path().stem().string())) continue;
        std::error_code rec;
        if (fs::remove(e.path(), rec)) ++n;
    }
    return n;
}

}  // namespace fringe
