// What an exported denoiser takes and returns, stored in the TorchScript file
// (extra file "dofarm/contract.json") so that the file alone is enough to use
// it: the input channels in order with the frame layer each comes from and
// its transform, the output and how to turn it back into radiance, the size
// rule, the recurrent state, the model config, the checkpoint and the version.
// The transforms are those of make_input() / make_target() (augment.h).
#pragma once

#include <string>

#include "trainer/run_folder.h"

namespace dofarm::trainer {

inline constexpr const char* kContractFile = "dofarm/contract.json";
inline constexpr const char* kContractFormat = "dofarm.denoiser/1";

// The contract as JSON text.
std::string denoiser_contract(const LoadedRun& run);

}  // namespace dofarm::trainer
