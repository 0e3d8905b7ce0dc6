// The analysis core's extension points and its pipeline: an estimator and an analyser
// registered from this file alone run end to end through fringe's run engine, and a report
// does not depend on how many threads the pipeline ran on.
#include "helpers.hpp"

#include "estimator/estimator.hpp"
#include "server/analysis/analyser.hpp"
#include "server/analysis/task_pool.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/fastmath.hpp"

#include <catch2/catch.hpp>

#include <atomic>
#include <cmath>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_analysers_cpp {

using namespace fringe;
using nlohmann::json;

namespace {

std::string encoders_dir() { return std::string(FRINGE_SOURCE_DIR) + "/fixtures/encoders"; }

// Ideal quadrature at 50 electrical cycles per second through a 16-bit loopback.
Scenario ideal_run(json estimators, double duration_s = 0.4) {
    const json j{{"name", "analysers"},
                 {"encoder", "ideal.json"},
                 {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 50.0}}},
                 {"sample_rate_hz", 20000},
                 {"duration_s", duration_s},
                 {"seed", 7},
                 {"settle_s", 0.05},
                 {"device", "loopback:?dac_bits=16&adc_bits=16"},
                 {"estimators", std::move(estimators)}};
    return scenario_from_json(j, encoders_dir());
}

// atan2 of the pair, unwrapped, plus a fixed offset: its mean error is the offset, whatever
// the noise does (atan2's own error has zero mean on ideal quadrature).
class OffsetAtan2 final : public est::Estimator {
public:
    static constexpr double kOffsetRad = 0.01;
    void reset(const est::EstimatorConfig& c) override { fs_ = c.sample_rate_hz; have_ = false; }
    void process(est::InputSpan in, est::OutputSpan out) override {
        for (std::size_t i = 0; i < in.size(); ++i) {
            const double w = std::atan2(in.sin_v[i], in.cos_v[i]);
            if (have_) {
                double d = w - last_wrapped_;
                d -= kTwoPi * std::round(d / kTwoPi);
                unwrapped_ += d;
            } else {
                unwrapped_ = w;
                have_ = true;
            }
            last_wrapped_ = w;
            out.theta_rad[i] = unwrapped_ + kOffsetRad;
            out.omega_rad_s[i] = std::numeric_limits<double>::quiet_NaN();
            out.valid[i] = 1;
        }
    }
    est::BoundClass bound_class() const override { return est::BoundClass::Memoryless; }

private:
    double fs_ = 0, unwrapped_ = 0, last_wrapped_ = 0;
    bool have_ = false;
};

// Counts what it is given: samples, valid samples, and the largest |theta_hat - theta_true|
// over valid samples after the settle time, minus the 2*pi multiple.
class CountingAnalyser final : public Analyser {
public:
    explicit CountingAnalyser(const LaneContext& c) : settle_s_(c.settle_s) {}
    void add(const LaneBlock& b) override {
        for (std::size_t i = 0; i < b.n; ++i) {
            if (!have_t0_) { t0_ = b.t_s[i]; have_t0_ = true; }
            ++samples_;
            if (!b.valid[i] || b.t_s[i] - t0_ < settle_s_) continue;
            ++valid_;
            const double e = b.theta_hat_rad[i] - b.theta_true_rad[i];
            max_abs_ = std::max(max_abs_, std::fabs(e - kTwoPi * std::round(e / kTwoPi)));
        }
    }
    void finish(LaneResults& r) override {
        r.extra["test-count"] = {{"samples", samples_}, {"scored", valid_}, {"max_abs_rad", max_abs_},
                                 {"truth_mean_rad", r.error ? json(r.error->mean_rad) : json()}};
    }

private:
    double settle_s_, t0_ = 0, max_abs_ = 0;
    bool have_t0_ = false;
    std::uint64_t samples_ = 0, valid_ = 0;
};

}  // namespace

TEST_CASE("analysers: an estimator and an analyser registered from a test file run end to end", "[analysers][run]") {
    est::ScopedEstimator estimator({"test-offset-atan2", "atan2 plus 0.01 rad (a test)", {},
                                    [] { return std::make_unique<OffsetAtan2>(); }, {}});
    ScopedAnalyser analyser({"test-count", "counts samples (a test)",
                             [](const LaneContext& c) { return std::make_unique<CountingAnalyser>(c); }});
    CHECK_THROWS_AS(register_analyser({"test-count", "again", [](const LaneContext& c) { return std::make_unique<CountingAnalyser>(c); }}),
                    std::invalid_argument);
    const Scenario sc = ideal_run(json::array({json{{"name", "test-offset-atan2"}}, json{{"name", "atan2"}}}));
    RunOptions o;
    o.block = 3000;  // many pipeline steps, blocks not a divisor of the run
    const json r = execute_run(sc, o);
    REQUIRE(r["status"] == "done");
    const std::uint64_t n = r["samples"]["processed"].get<std::uint64_t>();
    CHECK(n == sc.samples());
    REQUIRE(r["estimators"].size() == 2);
    for (const auto& e : r["estimators"]) {
        INFO(e["label"]);
        const json& c = e["analysers"]["test-count"];
        // the analyser saw every sample once, and the same scored samples as the truth scorer
        CHECK(c["samples"].get<std::uint64_t>() == n);
        CHECK(c["scored"] == e["metrics"]["scored"]);
        CHECK(c["max_abs_rad"].get<double>() == Approx(e["metrics"]["max_abs"]["rad"].get<double>()).epsilon(1e-12));
        CHECK(c["truth_mean_rad"].get<double>() == e["metrics"]["mean"]["rad"].get<double>());
    }
    // The test estimator's mean error is its offset (atan2's own mean on ideal quadrature is
    // below 1e-4 rad here; 2e-4 V noise on 1 V).
    const json& mine = r["estimators"][0];
    CHECK(mine["name"] == "test-offset-atan2");
    CHECK(mine["metrics"]["mean"]["rad"].get<double>() == Approx(OffsetAtan2::kOffsetRad).margin(1e-4));
    CHECK(std::fabs(r["estimators"][1]["metrics"]["mean"]["rad"].get<double>()) < 1e-4);
    // It is found with its (default) traits while registered; the next test case finds it gone.
    CHECK(est::find("test-offset-atan2").traits.child_process == false);
}

TEST_CASE("analysers: the registry names the built-in ones and removes a scoped one", "[analysers]") {
    auto names = [] {
        std::vector<std::string> v;
        for (const auto& a : analyser_registry()) v.push_back(a.name);
        return v;
    };
    CHECK(names() == std::vector<std::string>{"truth", "conventions", "spectrum", "self_reference"});
    {
        ScopedAnalyser a({"test-x", "x", [](const LaneContext& c) { return std::make_unique<CountingAnalyser>(c); }});
        CHECK(names().size() == 5);
    }
    CHECK(names().size() == 4);
    CHECK_THROWS_AS(est::find("test-offset-atan2"), ConfigError);
}

TEST_CASE("pipeline: the report is the same with one, two and three threads", "[analysers][run][threads]") {
    // Three lanes of different cost and a block that does not divide the run: the steps overlap
    // differently on each thread count, the figures must not.
    const Scenario sc = ideal_run(json::array({json{{"name", "ekf-ideal"}}, json{{"name", "atan2"}}, json{{"name", "pll2"}, {"params", {{"natural_freq_hz", 200}}}}}), 0.6);
    json reports[3];
    for (unsigned t = 1; t <= 3; ++t) {
        RunOptions o;
        o.block = 1700;
        o.threads = t;
        reports[t - 1] = execute_run(sc, o);
        REQUIRE(reports[t - 1]["status"] == "done");
    }
    for (int k = 1; k < 3; ++k) {
        INFO("threads " << k + 1 << " against 1");
        CHECK(reports[k]["estimators"] == reports[0]["estimators"]);
        CHECK(reports[k]["traces"] == reports[0]["traces"]);
        CHECK(reports[k]["measurements"] == reports[0]["measurements"]);
        CHECK(reports[k]["samples"] == reports[0]["samples"]);
        CHECK(reports[k]["verdict"] == reports[0]["verdict"]);
    }
}

TEST_CASE("pipeline: a task pool runs every task once and hands back each task's exception", "[analysers][threads]") {
    for (unsigned threads : {1u, 2u, 4u}) {
        TaskPool pool(threads);
        CHECK(pool.threads() == threads);
        std::vector<std::atomic<int>> hits(37);
        std::vector<std::function<void()>> tasks;
        for (std::size_t i = 0; i < hits.size(); ++i)
            tasks.emplace_back([&hits, i] {
                hits[i]++;
                if (i % 10 == 3) throw std::runtime_error("task " + std::to_string(i));
            });
        std::vector<std::exception_ptr> errors;
        for (int round = 0; round < 50; ++round) pool.run(tasks, errors);
        for (std::size_t i = 0; i < hits.size(); ++i) {
            CHECK(hits[i].load() == 50);
            CHECK(static_cast<bool>(errors[i]) == (i % 10 == 3));
        }
    }
}

namespace {
// Outputs atan2 but vouches for none of it (an estimator told the wrong signal model does this).
class NeverValid final : public est::Estimator {
public:
    void reset(const est::EstimatorConfig&) override {}
    void process(est::InputSpan in, est::OutputSpan out) override {
        for (std::size_t i = 0; i < in.size(); ++i) {
            out.theta_rad[i] = std::atan2(in.sin_v[i], in.cos_v[i]);
            out.omega_rad_s[i] = std::numeric_limits<double>::quiet_NaN();
            out.valid[i] = 0;
        }
    }
    est::BoundClass bound_class() const override { return est::BoundClass::Memoryless; }
};
}  // namespace

TEST_CASE("analysers: an estimator that vouches for nothing is diagnosed as such, with truth and without", "[analysers][run]") {
    est::ScopedEstimator never({"test-never-valid", "never valid (a test)", {}, [] { return std::make_unique<NeverValid>(); }, {}});
    for (const bool self_ref : {false, true}) {
        INFO((self_ref ? "self-referenced" : "truth-scored"));
        Scenario sc = ideal_run(json::array({json{{"name", "test-never-valid"}}, json{{"name", "atan2"}}}));
        sc.scoring.self_reference = self_ref;
        const json r = execute_run(sc);
        REQUIRE(r["status"] == "done");
        auto codes = [](const json& e) {
            std::vector<std::string> v;
            for (const auto& d : e["diagnosis"]) v.push_back(d["code"].get<std::string>());
            return v;
        };
        CHECK(codes(r["estimators"][0]) == std::vector<std::string>{"never_valid"});
        CHECK(codes(r["estimators"][1]).empty());  // atan2 vouches for its samples
        bool warned = false;
        for (const auto& w : r["warnings"]) warned |= w["code"] == "never_valid" && w["message"].get<std::string>().rfind("test-never-valid marked every sample", 0) == 0;
        CHECK(warned);
    }
}

}  // namespace test_analysers_cpp
