// Start-up lines: times per stage, the modes in plain words, progress of a slow start-up.
#include "startup_report.h"

#include <cstdio>
#include <sstream>

namespace modal_mass_spring
{
namespace
{

std::string seconds(double s)
{
  char text[32];
  if (s < 1.0)
    std::snprintf(text, sizeof text, "%.3g ms", 1e3 * s);
  else
    std::snprintf(text, sizeof text, "%.3g s", s);
  return text;
}

std::string number(double value)
{
  char text[32];
  std::snprintf(text, sizeof text, "%.4g", value);
  return text;
}

}  // namespace

std::string describeCoarseGrid(const Grid& grid, const Grid& coarse, int step_multiple)
{
  std::ostringstream out;
  out << "coarse grid " << coarse.params().rows << " x " << coarse.params().cols << " (" << coarse.numParticles()
      << " particles, " << number(static_cast<double>(grid.numParticles()) / coarse.numParticles())
      << " of the grid's a coarse one), stable to about " << step_multiple << " x time_step";
  return out.str();
}

std::string describeModes(const Eigen::VectorXd& frequencies, int num_zero_modes)
{
  const int r = static_cast<int>(frequencies.size());
  std::ostringstream out;
  out << r << (r == 1 ? " mode, " : " modes, ");
  if (r == 0)
    return out.str() + "none found";
  if (num_zero_modes >= r)
  {
    out << (r == 1 ? "zero" : "all zero")
        << " (frequency 0 rad/s: the grid has no stiffness along "
        << (r == 1 ? "it" : "any of them") << " at the linearization point, so the modal methods cannot "
        << "resist motion there; linearization: equilibrium gives a hanging sheet stiffness)";
    return out.str();
  }
  const Eigen::VectorXd nonzero = frequencies.tail(r - num_zero_modes);
  if (num_zero_modes == 0)
    out << number(frequencies.minCoeff()) << " to " << number(frequencies.maxCoeff()) << " rad/s, none zero";
  else
    out << num_zero_modes << " zero, the non-zero " << (r - num_zero_modes == 1 ? "one " : "ones ")
        << number(nonzero.minCoeff()) << " to " << number(nonzero.maxCoeff()) << " rad/s";
  return out.str();
}

std::string describeStartupTimes(const LinearizationInfo& linearization, const ModalBasis& basis, double total_seconds,
                                 const DerivativeBasisInfo& derivatives, const Cubature* cubature)
{
  std::ostringstream out;
  out << "start-up " << seconds(total_seconds) << ": ";
  if (linearization.equilibrium_solved)
    out << "equilibrium " << seconds(linearization.equilibrium_seconds) << ", ";
  out << "stiffness " << seconds(linearization.stiffness_seconds);
  if (basis.factorization_seconds > 0.0)
    out << ", factorisation " << seconds(basis.factorization_seconds);
  out << ", eigensolver " << seconds(std::max(0.0, basis.build_seconds - basis.factorization_seconds));
  if (derivatives.derivative_directions > 0)
    out << ", modal derivatives " << seconds(derivatives.seconds);
  if (cubature)
    out << ", cubature " << seconds(cubature->training_seconds);
  return out.str();
}

std::string describeBasis(const SimulationParams& params, const DerivativeBasisInfo& info, const ModalBasis& physical_basis,
                          const SkinningInfo& skinning)
{
  std::ostringstream out;
  out << "basis " << toString(params.basis);
  if (params.basis == BasisKind::LinearModes)
    return out.str();
  if (params.basis == BasisKind::Skinning)
  {
    out << " (" << describeSkinning(skinning);
    if (physical_basis.frequencies.size() > 0)
      out << ", frequencies up to " << number(physical_basis.frequencies.maxCoeff()) << " rad/s";
    out << "); `linear` keeps the " << params.num_modes << " lowest modes";
    return out.str();
  }
  out << ": " << info.linear_modes << " linear modes kept, " << info.derivative_directions
      << " derivative directions added (from " << info.derivatives_computed << " derivatives) in "
      << seconds(info.seconds);
  if (physical_basis.frequencies.size() > 0)
    out << ", frequencies up to " << number(physical_basis.frequencies.maxCoeff()) << " rad/s";
  out << "; singular values (relative to the largest) smallest kept " << number(info.smallest_kept_singular_value)
      << ", largest dropped " << number(info.largest_dropped_singular_value);
  return out.str();
}

std::string describeHandleFormulation(const GridParams& grid, const SimulationParams& params,
                                      const std::vector<std::string>& frames)
{
  const bool asked = params.handle_formulation != HandleFormulation::Auto;
  const std::string why = asked ? "handle_formulation: " + toString(params.handle_formulation)
                                : std::string("handle_formulation: auto");
  if (resolveHandleFormulation(grid, params) == HandleFormulation::MovingFrame)
    return "handles: moving frame of '" + frames.front() +
           "' (one rigid body holds every held particle and nothing is fixed: every method simulates in its frame, "
           "whose motion enters exactly at any turn; " + why + ")";
  std::ostringstream line;
  if (params.basis == BasisKind::Skinning)
    line << "handles: constraints on the skinning coordinates for physical and cubature, constraint modes "
            "(Craig-Bampton) for linear, prescribed positions for full; ";
  else
    line << "handles: constraint modes (Craig-Bampton) for the modal methods, prescribed positions for full; ";
  line << grid.handles.size() << (grid.handles.size() == 1 ? " handle" : " handles") << " on " << frames.size()
       << (frames.size() == 1 ? " frame" : " frames") << " (";
  const size_t fixed = effectiveFixed(grid).size();
  if (asked)
    line << "as " << why << " asks";
  else if (params.basis == BasisKind::Skinning)
    line << "the skinning span holds their rigid motion; no moving frame is needed";
  else if (frames.size() > 1)
    line << "they can move apart; the moving frame needs one rigid body";
  else
    line << fixed << " fixed " << (fixed == 1 ? "particle cannot" : "particles cannot")
         << " move with the frame; the moving frame needs none fixed";
  line << (params.basis == BasisKind::Skinning ? ")" : "; large turns distort the constraint modes)");
  return line.str();
}

std::string describeStage(const std::string& stage)
{
  if (stage == "equilibrium")
    return "solving the static equilibrium under gravity (equilibrium)";
  if (stage == "stiffness")
    return "assembling the stiffness matrix (stiffness)";
  if (stage == "factorisation")
    return "factorising the shifted stiffness matrix (factorisation)";
  if (stage == "eigensolver")
    return "computing the modes (eigensolver)";
  if (stage == "modal derivatives")
    return "computing the modal derivatives and their directions (modal derivatives)";
  if (stage == "skinning")
    return "computing the skinning weights and subspace (skinning)";
  if (stage == "cubature")
    return "training the cubature's springs and weights (cubature)";
  return stage;
}

StartupProgress::StartupProgress(std::function<void(const std::string&)> log, std::function<double()> now,
                                 double quiet_seconds, double repeat_seconds, std::string activity,
                                 double iteration_seconds)
  : log_(std::move(log)),
    now_(std::move(now)),
    quiet_seconds_(quiet_seconds),
    repeat_seconds_(repeat_seconds),
    activity_(std::move(activity)),
    iteration_seconds_(iteration_seconds)
{
  start_ = stage_start_ = now_();
}

void StartupProgress::onStage(const std::string& stage)
{
  std::lock_guard<std::mutex> lock(mutex_);
  stage_ = stage;
  stage_start_ = now_();
  iteration_.clear();
  iteration_new_ = false;
}

void StartupProgress::onIteration(const std::string& stage, int iteration, double residual, double target)
{
  char text[160];
  if (stage == "equilibrium")
    std::snprintf(text, sizeof text, "Newton iteration %d, largest unbalanced force %.3g N (target %.3g N)", iteration,
                  residual, target);
  else if (stage == "cubature")
    std::snprintf(text, sizeof text, "%d springs selected, training error %.3g%% (cubature_tolerance %.3g%%)",
                  iteration, 100.0 * residual, 100.0 * target);
  else
    std::snprintf(text, sizeof text, "%s step %d, residual %.3g (target %.3g)",
                  stage == "eigensolver" ? "Lanczos" : stage.c_str(), iteration, residual, target);
  std::lock_guard<std::mutex> lock(mutex_);
  iteration_ = text;
  iteration_new_ = true;
}

void StartupProgress::poll()
{
  std::string line;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const double t = now_();
    if (t - start_ < quiet_seconds_)
      return;
    const bool new_stage = stage_ != reported_stage_;
    const bool moved = iteration_new_ && t - last_report_ >= iteration_seconds_;
    if (!new_stage && !moved && t - last_report_ < repeat_seconds_)
      return;
    std::ostringstream out;
    char text[128];
    std::snprintf(text, sizeof text, " for %.1f s: ", t - start_);
    out << activity_ << text << describeStage(stage_);
    if (!new_stage || t - stage_start_ >= quiet_seconds_)
    {
      std::snprintf(text, sizeof text, ", for %.1f s so far", t - stage_start_);
      out << text;
    }
    if (!iteration_.empty())
      out << ": " << iteration_;
    iteration_new_ = false;
    line = out.str();
    reported_stage_ = stage_;
    last_report_ = t;
  }
  log_(line);
}

}  // namespace modal_mass_spring
