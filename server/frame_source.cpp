#include "frame_source.hpp"

#include "signal_gen/generator.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>

namespace fringe {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

class StepSource final : public FrameSource {
public:
    StepSource(const Scenario& sc, dev::Device& d, bool dut)
        : sc_(sc), dev_(d), gen_(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed, sc.t0_s), dut_(dut) {}
    SourceStatus next(std::size_t max, Frames& out) override {
        // Static steps are slow (a settle each): small blocks keep progress and cancel prompt.
        const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>({max, 16, sc_.samples() - k_}));
        b_.resize(n, sc_.encoder.index.enabled);
        gen_.generate(k_, b_);
        out.resize(n, dut_);
        for (std::size_t i = 0; i < n; ++i) {
            const dev::StepResult r = dev_.step(b_.sin_v[i], b_.cos_v[i], -1.0, 0);  // the device's settle and averaging
            out.sin_v[i] = r.sin_v;
            out.cos_v[i] = r.cos_v;
            if (dut_) out.dut_theta_rad[i] = r.dut_theta_rad ? *r.dut_theta_rad : kNaN;
            out.t_s[i] = b_.t_s[i];
            out.theta_true_rad[i] = b_.theta_rad[i];
            out.omega_true_rad_s[i] = b_.omega_rad_s[i];
            out.truth_known[i] = 1;
        }
        k_ += n;
        return {};
    }

private:
    const Scenario& sc_;
    dev::Device& dev_;
    Generator gen_;
    Block b_;
    std::uint64_t k_ = 0;
    bool dut_;
};

class StreamSource final : public FrameSource {
public:
    StreamSource(const Scenario& sc, dev::Device& d, const dev::DeviceInfo& info, std::size_t block)
        : sc_(sc), dev_(d), gen_(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed, sc.t0_s), block_(block), total_(sc.samples()) {
        // The first latency_samples input frames predate the signal and are not scored.
        for (int k = 0; k < info.latency_samples; ++k) pending_.push_back({sc.t0_s + k / sc.sample_rate_hz, 0, 0, false});
        dev_.start(sc.sample_rate_hz);
        started_ = true;
    }
    ~StreamSource() override { stop(); }
    void stop() override {
        if (started_) {
            started_ = false;
            dev_.stop();
        }
    }
    SourceStatus next(std::size_t max, Frames& out) override {
        const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(max, total_ - k_in_));
        // Output runs up to four blocks ahead of input: a real-time board (USB) must never run
        // dry while the host reads. Truth is queued as it is written.
        while (k_out_ < std::min<std::uint64_t>(total_, k_in_ + 4 * block_)) {
            const std::size_t nw = static_cast<std::size_t>(std::min<std::uint64_t>(block_, total_ - k_out_));
            b_.resize(nw, sc_.encoder.index.enabled);
            gen_.generate(k_out_, b_);
            const auto w = dev_.write(b_.sin_v, b_.cos_v);
            if (w.status != dev::StreamStatus::Ok)
                return {false, false, std::string("output ") + dev::to_string(w.status) + " at sample " + std::to_string(k_out_ + w.frames) + ": " + w.message};
            for (std::size_t i = 0; i < nw; ++i) pending_.push_back({b_.t_s[i], b_.theta_rad[i], b_.omega_rad_s[i], true});
            k_out_ += nw;
            if (k_out_ == total_) dev_.end_of_output();
        }
        out.resize(want, false);
        std::size_t got = 0;
        while (got < want) {
            const auto r = dev_.read(std::span(out.sin_v).subspan(got), std::span(out.cos_v).subspan(got), 1000);
            if (r.status == dev::StreamStatus::Overflow || r.dropped) {
                out.resize(got, false);
                fill_truth(out);
                return {false, false, "sample loss: " + std::to_string(r.dropped) + " input samples dropped before input sample " +
                                          std::to_string(r.first_index) + " (" + r.message + ")"};
            }
            if (r.status != dev::StreamStatus::Ok || r.frames == 0) {
                const std::string what = r.status != dev::StreamStatus::Ok ? std::string("input ") + dev::to_string(r.status) + " at input sample " + std::to_string(k_in_ + got) + ": " + r.message
                                                                             : "input underrun: the device returned no samples at input sample " + std::to_string(k_in_ + got);
                out.resize(got, false);
                fill_truth(out);
                return {false, false, what};
            }
            got += r.frames;
        }
        fill_truth(out);
        return {};
    }

private:
    struct Truth { double t, th, om; bool known; };
    void fill_truth(Frames& out) {
        for (std::size_t i = 0; i < out.size(); ++i) {
            const Truth tr = pending_.front();
            pending_.pop_front();
            out.t_s[i] = tr.t;
            out.theta_true_rad[i] = tr.th;
            out.omega_true_rad_s[i] = tr.om;
            out.truth_known[i] = tr.known;
        }
        k_in_ += out.size();
    }
    const Scenario& sc_;
    dev::Device& dev_;
    Generator gen_;
    Block b_;
    std::size_t block_;
    std::uint64_t total_, k_out_ = 0, k_in_ = 0;
    std::deque<Truth> pending_;
    bool started_ = false;
};

class ReplaySource final : public FrameSource {
public:
    ReplaySource(const Scenario& sc, dev::Device& d, bool dut) : sc_(sc), dev_(d), total_(sc.samples()), dut_(dut) {
        dev_.start(sc.sample_rate_hz);
        started_ = true;
    }
    ~ReplaySource() override { stop(); }
    void stop() override {
        if (started_) {
            started_ = false;
            dev_.stop();
        }
    }
    SourceStatus next(std::size_t max, Frames& out) override {
        const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(max, total_ - k_));
        out.resize(want, dut_);
        std::size_t got = 0;
        while (got < want) {
            const auto r = dev_.read(std::span(out.sin_v).subspan(got), std::span(out.cos_v).subspan(got), 1000);
            if (r.status != dev::StreamStatus::Ok || r.dropped) {
                out.resize(got, dut_);
                k_ += got;
                return {false, false, std::string("input ") + dev::to_string(r.status) + " at input sample " + std::to_string(k_) + ": " + r.message};
            }
            if (r.frames == 0) {  // the capture's end
                out.resize(got, dut_);
                k_ += got;
                return {true, true, ""};
            }
            th_.resize(r.frames);
            om_.resize(r.frames);
            const bool has = dev_.last_truth(th_, om_);
            if (dut_ && !dev_.last_dut(std::span(out.dut_theta_rad).subspan(got, r.frames)))
                std::fill_n(out.dut_theta_rad.begin() + static_cast<std::ptrdiff_t>(got), r.frames, kNaN);
            for (std::size_t i = 0; i < r.frames; ++i) {
                out.t_s[got + i] = sc_.t0_s + static_cast<double>(k_ + got + i) / sc_.sample_rate_hz;
                out.theta_true_rad[got + i] = has ? th_[i] : kNaN;
                out.omega_true_rad_s[got + i] = has ? om_[i] : kNaN;
                out.truth_known[got + i] = has;
            }
            got += r.frames;
        }
        k_ += got;
        return {};
    }

private:
    const Scenario& sc_;
    dev::Device& dev_;
    std::uint64_t total_, k_ = 0;
    std::vector<double> th_, om_;
    bool started_ = false;
    bool dut_;
};

}  // namespace

void Frames::resize(std::size_t n, bool dut) {
    t_s.resize(n); sin_v.resize(n); cos_v.resize(n);
    theta_true_rad.resize(n); omega_true_rad_s.resize(n); truth_known.resize(n);
    dut_theta_rad.resize(dut ? n : 0);
}

std::unique_ptr<FrameSource> make_frame_source(const Scenario& sc, dev::Device& device, const dev::DeviceInfo& info,
                                               std::size_t block) {
    if (!info.streaming && info.step_mode) return std::make_unique<StepSource>(sc, device, info.dut_position);
    if (!info.needs_output) return std::make_unique<ReplaySource>(sc, device, info.dut_position);
    return std::make_unique<StreamSource>(sc, device, info, block);
}

}  // namespace fringe
