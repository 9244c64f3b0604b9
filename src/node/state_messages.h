// The simulation's saved state (SimulationState) as a message (SavedState) and back.
#pragma once

#include "handle_frames.h"
#include "modal_mass_spring/SavedState.h"
#include "modal_mass_spring/simulation.h"

#include <geometry_msgs/Pose.h>

namespace modal_mass_spring
{

geometry_msgs::Pose poseMessage(const FramePose& pose);
FramePose framePose(const geometry_msgs::Pose& pose);

// The state, with the handle frames' poses and the particles' positions (fixed frame: the grid's
// positions shifted by `offset`) for the reader.
SavedState stateMessage(const SimulationState& state, const HandleFrames& frames, const Eigen::Matrix3Xd& points,
                        const Eigen::Vector3d& offset);
// The message's state; throws std::invalid_argument naming the field (an unknown method, a
// frame_motion of the wrong size, handle frames that are not the node's) for what cannot be read.
// Sizes against the grid are the core's to check (Simulation::restoreState).
SimulationState simulationState(const SavedState& message, const HandleFrames& frames);
// Puts the handle frames where the message has them (HandleFrames::place).
void placeHandleFrames(const SavedState& message, HandleFrames& frames);

}  // namespace modal_mass_spring
