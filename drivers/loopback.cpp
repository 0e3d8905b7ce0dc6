// loopback: the fully simulated converter chain (DESIGN.md "Converter"):
//   DAC (bits, range; zero-order hold at the stream rate) -> reconstruction filter (1st order)
//   -> analog noise -> anti-alias filter (1st or 2nd order Butterworth) -> ADC (bits, range,
//   clipping) -> latency. Fault injection for tests: drop samples, stall, saturate.
// Samples are processed when written, so read() only hands out what the chain produced.
#include "device.hpp"

#include "signal_gen/config.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/noise.hpp"
#include "signal_gen/quantizer.hpp"

#include <cmath>
#include <deque>

namespace fringe::dev {

namespace {

// Bilinear-transform low-pass sections with prewarping (exact cutoff).
struct Biquad {
    double b0 = 1, b1 = 0, b2 = 0, a1 = 0, a2 = 0, z1 = 0, z2 = 0;
    double step(double x) {  // transposed direct form II
        const double y = b0 * x + z1;
        z1 = b1 * x - a1 * y + z2;
        z2 = b2 * x - a2 * y;
        return y;
    }
    static Biquad lowpass(int order, double fc_hz, double fs_hz) {
        Biquad q;
        if (fc_hz <= 0) return q;
        const double k = std::tan(kPi * fc_hz / fs_hz);
        if (order == 1) {
            const double n = 1 / (1 + k);
            q.b0 = q.b1 = k * n;
            q.a1 = (k - 1) * n;
        } else {
            const double sq2 = std::sqrt(2.0), n = 1 / (1 + sq2 * k + k * k);
            q.b0 = k * k * n; q.b1 = 2 * q.b0; q.b2 = q.b0;
            q.a1 = 2 * (k * k - 1) * n;
            q.a2 = (1 - sq2 * k + k * k) * n;
        }
        return q;
    }
};

class Loopback final : public Device {
public:
    Loopback(std::string uri, const nlohmann::json& s) : uri_(std::move(uri)), s_(s) {
        const double range = s.at("range_v").get<double>();
        dac_ = Quantizer{s.at("dac_bits").get<int>(), -range, range};
        adc_ = Quantizer{s.at("adc_bits").get<int>(), -range, range};
        latency_ = s.at("latency_samples").get<int>();
        noise_v_ = s.at("noise_v").get<double>();
        rng_ = Xoshiro256pp(static_cast<std::uint64_t>(s.at("seed").get<long long>()));
        drop_after_ = s.at("drop_after").get<long long>();
        drop_count_ = s.at("drop_count").get<long long>();
        stall_after_ = s.at("stall_after").get<long long>();
        saturate_after_ = s.at("saturate_after").get<long long>();
    }
    DeviceInfo info() const override {
        DeviceInfo i;
        i.driver = "loopback";
        i.uri = uri_;
        i.description = "simulated DAC -> filters -> noise -> ADC";
        i.board_id = "loopback";
        i.streaming = true;
        i.step_mode = true;
        i.latency_samples = latency_;
        i.settings = s_;
        i.converter.known = true;
        i.converter.dac_bits = dac_.bits;
        i.converter.adc_bits = adc_.bits;
        i.converter.dac_range_v = i.converter.adc_range_v = adc_.max_v;
        // White analog noise through the anti-alias filter: its variance scales by sum h[n]^2.
        const double fs = fs_ > 0 ? fs_ : 0.0;
        double gain2 = 1.0;
        if (fs > 0 && s_.at("aa_cutoff_hz").get<double>() > 0) {
            Biquad f = Biquad::lowpass(s_.at("aa_order").get<int>(), s_.at("aa_cutoff_hz").get<double>(), fs);
            gain2 = 0;
            for (int n = 0; n < 200000; ++n) {
                const double h = f.step(n == 0 ? 1.0 : 0.0);
                gain2 += h * h;
                if (n > 64 && std::fabs(h) < 1e-12) break;
            }
        }
        i.converter.noise_at_adc_v = noise_v_ * std::sqrt(gain2);
        if (fs <= 0 && s_.at("aa_cutoff_hz").get<double>() > 0) i.converter.note = "noise before the anti-alias filter (not started)";
        else i.converter.note = "filters' effect on the signal amplitude is not in the bound";
        // With little noise between them, an ADC on the DAC's own grid reads back the DAC's
        // codes (filters only blur the steps between held codes): no quantisation of its own.
        // Measured: 8-bit DAC and ADC, with or without a 40 kHz anti-alias filter, give the
        // 8-bit DAC's error alone to 10 digits (tests/test_evidence.cpp).
        const double qd = i.converter.dac_q_v(), qa = i.converter.adc_q_v(), n = i.converter.noise_at_adc_v;
        if (dac_.bits > 0 && dac_.bits == adc_.bits && n < qa / 4) {
            i.converter.added_noise_v = std::sqrt(qd * qd / 12 + n * n);
            i.converter.note += "; the ADC re-reads the DAC's grid (same bits and range, analog noise < q/4): one quantisation";
        } else {
            i.converter.added_noise_v = i.converter.independent_noise_v();
        }
        return i;
    }
    void start(double fs) override {
        if (!(fs > 0)) throw DeviceError(uri_, "sample rate must be positive");
        fs_ = fs;
        for (int ch = 0; ch < 2; ++ch) {
            recon_[ch] = Biquad::lowpass(1, s_.at("recon_cutoff_hz").get<double>(), fs);
            aa_[ch] = Biquad::lowpass(s_.at("aa_order").get<int>(), s_.at("aa_cutoff_hz").get<double>(), fs);
        }
        queue_.clear();
        for (int k = 0; k < latency_; ++k) queue_.push_back({adc_.apply(0.0), adc_.apply(0.0), 0.0});
        written_ = read_ = 0;
        pending_drop_ = 0;
        last_update_ = -1;
        dac_rate_hz_ = s_.at("dac_rate_hz").get<double>();
        if (dac_rate_hz_ > fs) throw DeviceError(uri_, "dac_rate_hz above the stream rate is not simulated (it must be <= the sample rate)");
        running_ = true;
    }
    StreamResult write(std::span<const double> s, std::span<const double> c) override {
        if (!running_) throw DeviceError(uri_, "write before start");
        for (std::size_t i = 0; i < s.size(); ++i, ++written_) {
            const long long k = static_cast<long long>(written_);
            // DAC update rate: a new code is latched when floor(k*dac_rate/fs) advances
            // (zero-order hold in between); 0 means every sample.
            const std::int64_t u = dac_rate_hz_ > 0 ? static_cast<std::int64_t>(std::floor(static_cast<double>(k) * dac_rate_hz_ / fs_)) : k;
            if (u != last_update_) {
                held_[0] = dac_.apply(s[i]);
                held_[1] = dac_.apply(c[i]);
                last_update_ = u;
            }
            double v[2] = {held_[0], held_[1]};
            for (int ch = 0; ch < 2; ++ch) {
                double a = recon_[ch].step(v[ch]);
                if (noise_v_ > 0) a += noise_v_ * standard_normal(rng_);
                a = aa_[ch].step(a);
                if (saturate_after_ >= 0 && k >= saturate_after_) a = 2 * adc_.max_v;  // driven into the rail
                if (adc_.clips(a)) ++clipped_;
                v[ch] = adc_.apply(a);
            }
            if (drop_after_ >= 0 && k >= drop_after_ && k < drop_after_ + drop_count_) {
                ++pending_drop_;  // lost on the way in: the gap is reported where it happened
                continue;
            }
            queue_.push_back({v[0], v[1], static_cast<double>(pending_drop_)});
            pending_drop_ = 0;
        }
        return {StreamStatus::Ok, s.size(), 0, 0, {}};
    }
    StreamResult read(std::span<double> s, std::span<double> c, int) override {
        StreamResult r;
        r.first_index = read_ + dropped_total_;
        const double gap = !queue_.empty() ? queue_.front()[2] : static_cast<double>(pending_drop_);
        if (gap > 0) {  // samples were lost just before the next frame
            const auto lost = static_cast<std::uint64_t>(gap);
            if (!queue_.empty()) queue_.front()[2] = 0; else pending_drop_ = 0;
            r.status = StreamStatus::Overflow;
            r.dropped = lost;
            dropped_total_ += lost;
            r.first_index = read_ + dropped_total_;
            r.message = std::to_string(lost) + " input samples lost (injected: drop_after/drop_count)";
            return r;
        }
        if (stall_after_ >= 0 && static_cast<long long>(read_) >= stall_after_) {
            r.status = StreamStatus::Timeout;
            r.message = "no input after sample " + std::to_string(read_) + " (injected: stall_after)";
            return r;
        }
        std::size_t n = std::min(s.size(), queue_.size());
        for (std::size_t i = 1; i < n; ++i)  // stop before the next gap
            if (queue_[i][2] > 0) { n = i; break; }
        if (stall_after_ >= 0) n = std::min<std::size_t>(n, static_cast<std::size_t>(stall_after_ - static_cast<long long>(read_)));
        for (std::size_t i = 0; i < n; ++i) {
            s[i] = queue_.front()[0];
            c[i] = queue_.front()[1];
            queue_.pop_front();
        }
        read_ += n;
        r.frames = n;
        return r;
    }
    void stop() override { running_ = false; }
    StepResult step(double s, double c, double settle_s, int average) override {
        // Static pair: the filters settle (run settle_s of samples), then average ADC reads.
        if (!running_) start(fs_ > 0 ? fs_ : 100e3);
        const auto settle = static_cast<std::size_t>(std::ceil(std::max(settle_s, 0.0) * fs_)) + static_cast<std::size_t>(latency_);
        const std::size_t n = settle + static_cast<std::size_t>(std::max(average, 1));
        std::vector<double> vs(n, s), vc(n, c), rs(n), rc(n);
        write(vs, vc);
        std::size_t got = 0;
        while (got < n) {
            const auto r = read(std::span(rs).subspan(got), std::span(rc).subspan(got), 0);
            if (r.status != StreamStatus::Ok) throw DeviceError(uri_, std::string("step: ") + to_string(r.status) + ": " + r.message);
            if (!r.frames) break;
            got += r.frames;
        }
        StepResult out;
        const std::size_t m = static_cast<std::size_t>(std::max(average, 1));
        for (std::size_t i = n - m; i < n; ++i) { out.sin_v += rs[i] / static_cast<double>(m); out.cos_v += rc[i] / static_cast<double>(m); }
        return out;
    }

private:
    std::string uri_;
    nlohmann::json s_;
    Quantizer dac_, adc_;
    Biquad recon_[2], aa_[2];
    int latency_ = 0;
    double noise_v_ = 0, fs_ = 0;
    Xoshiro256pp rng_{1};
    std::deque<std::array<double, 3>> queue_;  // sin, cos, samples lost just before this frame
    std::uint64_t written_ = 0, read_ = 0, pending_drop_ = 0, dropped_total_ = 0, clipped_ = 0;
    long long drop_after_ = -1, drop_count_ = 0, stall_after_ = -1, saturate_after_ = -1;
    bool running_ = false;
    double dac_rate_hz_ = 0, held_[2] = {0, 0};
    std::int64_t last_update_ = -1;
};

}  // namespace

void register_loopback(std::vector<DriverInfo>& r) {
    DriverInfo d;
    d.scheme = "loopback";
    d.summary = "Fully simulated converter chain: DAC, reconstruction filter, analog noise, anti-alias filter, ADC, latency; fault injection";
    d.settings = {
        {"dac_bits", "bit", ParamType::Integer, 16, 0, 24, {}, "DAC resolution (0: ideal)"},
        {"adc_bits", "bit", ParamType::Integer, 16, 0, 24, {}, "ADC resolution (0: ideal)"},
        {"range_v", "V", ParamType::Number, 1.25, 1e-3, 100, {}, "DAC and ADC full scale [-range_v, range_v)"},
        {"dac_rate_hz", "Hz", ParamType::Number, 0.0, 0, 1e10, {}, "DAC update rate, zero-order hold in between (0: the stream rate; at most the stream rate)"},
        {"recon_cutoff_hz", "Hz", ParamType::Number, 0.0, 0, 1e9, {}, "reconstruction filter (1st order) cutoff; 0: none"},
        {"aa_cutoff_hz", "Hz", ParamType::Number, 0.0, 0, 1e9, {}, "anti-alias filter cutoff; 0: none"},
        {"aa_order", "", ParamType::Integer, 2, 1, 2, {}, "anti-alias filter order (Butterworth)"},
        {"noise_v", "V", ParamType::Number, 0.0, 0, 10, {}, "analog noise per channel, rms"},
        {"seed", "", ParamType::Integer, 1, 0, 9e15, {}, "analog noise seed"},
        {"latency_samples", "samples", ParamType::Integer, 0, 0, 1e6, {}, "pure delay from DAC to ADC"},
        {"drop_after", "samples", ParamType::Integer, -1, -1, 9e15, {}, "fault: lose drop_count input samples from this index (-1: never)"},
        {"drop_count", "samples", ParamType::Integer, 0, 0, 9e15, {}, "fault: how many"},
        {"stall_after", "samples", ParamType::Integer, -1, -1, 9e15, {}, "fault: no input after this many samples (-1: never)"},
        {"saturate_after", "samples", ParamType::Integer, -1, -1, 9e15, {}, "fault: drive the ADC into its rail from this index (-1: never)"},
    };
    d.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        if (!path.empty()) throw ConfigError("device", "loopback takes no path (got '" + path + "'); use loopback:?key=value");
        return std::make_unique<Loopback>(uri, s);
    };
    r.push_back(std::move(d));
}

}  // namespace fringe::dev
