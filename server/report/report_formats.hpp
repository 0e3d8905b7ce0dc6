// Report renderings: JUnit XML (one testcase per measurement, with
// value, unit and limits as properties) and a self-contained HTML page with inline SVG plots
// (Lissajous, error vs electrical angle, error vs time, harmonic bars) that opens offline.
#pragma once

#include <nlohmann/json.hpp>

#include <string>

namespace fringe {

std::string junit_xml(const nlohmann::json& report);
std::string report_html(const nlohmann::json& report);
// The estimators' summary table (the metric table's summary columns) and the table of every
// metric of every lane (HTML, as in report_html).
std::string metric_tables_html(const nlohmann::json& report);
// Every metric of every lane as text (`fringe run --metrics`, `fringe runs show --metrics`).
std::string metrics_text(const nlohmann::json& report);
std::string xml_escape(const std::string& s);
// Writes via a temporary file and rename, so a reader never sees half a file.
void write_file_atomic(const std::string& path, const std::string& text);

}  // namespace fringe
