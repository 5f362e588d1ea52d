#pragma once

// The `estimation:` block every calibration result file writes (and reads back) for its
// EstimationReport, in one format. Private to calibration/ (yaml-cpp stays out of public
// headers). Format, under the key `estimation`:
//
//   estimator: text            status: converged | unidentified | not-converged | ...
//   message: text              iterations: n
//   initial_cost, final_cost, variance_factor: numbers (.nan when not defined)
//   residuals: list of {name, unit, count, mean, rms, max_abs}
//   parameters: list of {name, unit, initial, value, sigma, estimated, identified}
//   covariance: n×n numbers row by row (empty list when not computed)
//   identifiability: {parameters, rank, condition_number, condition_number_identified,
//                     singular_values, unidentified, gauges, strong_correlations}
//   warnings: list of text

#include <yaml-cpp/yaml.h>

#include <string>

#include "calibration/common/estimation.h"
#include "calibration/common/yaml_reader_internal.h"

namespace kinevis::calibration::internal {

// Writes `key: {...}` into an open map of `out`.
void EmitEstimation(YAML::Emitter& out, const EstimationReport& report,
                    const std::string& key = "estimation");

// Reads the block at node[key]; every missing or bad field is reported to `in` under
// "<key>.<field>". The report read is checked with EstimationReport::Validate().
EstimationReport ReadEstimation(CheckedYamlReader& in, const YAML::Node& node,
                                const std::string& key = "estimation");

}  // namespace kinevis::calibration::internal
