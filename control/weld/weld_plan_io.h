#pragma once

// A weld plan on disk and on screen (issue 7): the plan as YAML (layer → bead → point, the joint
// trajectory the robot consumes, the reference surface and the summary; every key and unit in
// docs/weld-paths.md), and two PNGs: the top view (depth map with the beads over it) and a section
// through a cavity (scan, reference, layers). yaml-cpp and OpenCV are used in the .cc only.
// Lengths are written in mm, angles in degrees, speeds in mm/s, times in s (the unit is in each
// key's name); positions and axes are in the robot base frame 0.

#include <string>

#include "control/weld/weld_planner.h"

namespace kinevis::control {

struct WeldPlanMetadata {
  std::string created;  // UTC ISO 8601; empty: now, on write
  std::string source;   // the map it was planned from (a PLY path, "synthetic", ...)
  std::string robot;    // the robot description used ("" = built-in Weld5Model::Seed)
};

// Writes the plan. Throws std::runtime_error naming the path when it cannot be written.
void WriteWeldPlan(const std::string& path, const WeldPlan& plan,
                   const WeldPlanMetadata& metadata = {});

struct WeldPlanFile {
  // Everything the file holds: options (those in the file; the rest at their defaults), the
  // reference surface and its statistics, regions, layers, beads, points (with IK status and
  // joints), rejected regions, the trajectory and its sources, the summary. The depth grid is not
  // stored (FillCoverage needs the planner's plan; the file keeps the coverage it computed).
  WeldPlan plan;
  WeldPlanMetadata metadata;
};

// Reads a file written by WriteWeldPlan. Throws std::runtime_error when it cannot be read or
// parsed, std::invalid_argument naming the file and every missing or bad key (with its value) in
// one message.
WeldPlanFile ReadWeldPlan(const std::string& path);

// Top view in R (x_R right, y_R up): the depth below the reference of every grid cell (colour
// map, 0 → the deepest region's depth; no data black), the damaged regions' outlines (white),
// rejected regions (magenta circles), each bead's arc-on path (one colour per layer; unreachable
// beads red), a 10 mm scale bar and a legend. Needs the plan from PlanWeldRepair (the grid).
// Throws std::invalid_argument for a plan without a grid, std::runtime_error when the file
// cannot be written.
void WriteWeldPlanTopView(const std::string& path, const WeldPlan& plan);

// Section along x_R through the deepest cell of region `region` (index into plan.regions): the
// scanned surface (cell medians, height relative to the reference, mm), the reference (0), the
// damage threshold, and for every layer its deposition surface under the bead points near the
// section (mm) and its slice bottom. Throws std::invalid_argument for a region index out of range
// or a plan without a grid, std::runtime_error when the file cannot be written.
void WriteWeldPlanSection(const std::string& path, const WeldPlan& plan, int region = 0);

}  // namespace kinevis::control
