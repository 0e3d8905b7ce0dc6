// A fixed set of worker threads that run one batch of independent tasks at a time; the caller
// works too and returns when the batch is done. The run engine's pipeline steps use it: the
// frame source, each lane and the traces of different blocks side by side, each task on data no
// other task of the batch touches, so results do not depend on the thread count.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace fringe {

class TaskPool {
public:
    // threads: the total (the caller included); 1 runs every task on the caller, in order.
    explicit TaskPool(unsigned threads) {
        for (unsigned i = 1; i < threads; ++i) workers_.emplace_back([this] { work(); });
    }
    ~TaskPool() {
        {
            std::lock_guard lock(m_);
            stop_ = true;
        }
        cv_.notify_all();
        for (auto& w : workers_) w.join();
    }
    TaskPool(const TaskPool&) = delete;
    TaskPool& operator=(const TaskPool&) = delete;

    unsigned threads() const { return static_cast<unsigned>(workers_.size()) + 1; }

    // Runs every task; each task's exception is kept in errors[i] (null when it finished).
    void run(const std::vector<std::function<void()>>& tasks, std::vector<std::exception_ptr>& errors) {
        errors.assign(tasks.size(), nullptr);
        if (workers_.empty() || tasks.size() < 2) {
            for (std::size_t i = 0; i < tasks.size(); ++i) call(tasks[i], errors[i]);
            return;
        }
        {
            std::lock_guard lock(m_);
            tasks_ = &tasks;
            errors_ = &errors;
            next_.store(0);
            pending_ = tasks.size();
            ++batch_;
        }
        cv_.notify_all();
        drain(&tasks, &errors);
        // Every task done, and no worker still inside this batch (it holds its pointers).
        std::unique_lock lock(m_);
        done_cv_.wait(lock, [this] { return pending_ == 0 && active_ == 0; });
        tasks_ = nullptr;
        errors_ = nullptr;
    }

private:
    static void call(const std::function<void()>& f, std::exception_ptr& err) {
        try {
            f();
        } catch (...) {
            err = std::current_exception();
        }
    }
    // Takes tasks of the current batch until none is left.
    void drain(const std::vector<std::function<void()>>* tasks, std::vector<std::exception_ptr>* errors) {
        for (;;) {
            const std::size_t i = next_.fetch_add(1);
            if (i >= tasks->size()) return;
            call((*tasks)[i], (*errors)[i]);
            std::lock_guard lock(m_);
            if (--pending_ == 0) done_cv_.notify_all();
        }
    }
    void work() {
        std::uint64_t seen = 0;
        for (;;) {
            const std::vector<std::function<void()>>* tasks = nullptr;
            std::vector<std::exception_ptr>* errors = nullptr;
            {
                std::unique_lock lock(m_);
                cv_.wait(lock, [&] { return stop_ || (batch_ != seen && tasks_ != nullptr); });
                if (stop_) return;
                seen = batch_;
                tasks = tasks_;
                errors = errors_;
                ++active_;
            }
            drain(tasks, errors);
            {
                std::lock_guard lock(m_);
                --active_;
            }
            done_cv_.notify_all();
        }
    }

    std::vector<std::thread> workers_;
    std::mutex m_;
    std::condition_variable cv_, done_cv_;
    const std::vector<std::function<void()>>* tasks_ = nullptr;
    std::vector<std::exception_ptr>* errors_ = nullptr;
    std::atomic<std::size_t> next_{0};
    std::size_t pending_ = 0;
    std::size_t active_ = 0;  // workers inside the current batch
    std::uint64_t batch_ = 0;
    bool stop_ = false;
};

}  // namespace fringe
