#pragma once
/// @file StepOrder.h
/// @brief Derives the initialisation and step order of a scene's effects from their
/// declarations (Effect::declaration()), and refuses scenes whose effects disagree on what a name
/// means.
///
/// - Initialisation: an effect that initialises a key (kInitialises) comes before every effect
///   that reads it at initialisation (kReadsAtInit); otherwise by stage, then scene order.
/// - Steps: by stage (sources, walkers, phase field, obstacle copy, fluid, heat advection: the
///   ice paper's order); within a stage, writers of a key before its readers, then scene order.
/// - Refused: two effects using one field or output name with different meanings (type, unit or
///   meaning differ), and circular initialisation.
#include <frostvdb/core/Effect.h>

#include <string>
#include <vector>

namespace frostvdb {

struct DeclaredEffect {
    std::string section;
    FieldDeclaration declaration;
};

struct EffectOrder {
    std::vector<size_t> initialize; ///< indices into the input, in initialisation order
    std::vector<size_t> step;       ///< indices into the input, in step order
};

/// Throws SceneError (naming @a sceneLabel and the sections involved) on a conflict or a cycle.
EffectOrder deriveEffectOrder(const std::vector<DeclaredEffect>& effects, const std::string& sceneLabel);

/// True when two keys mean the same thing (name, type, unit and meaning agree).
bool sameMeaning(const FieldKey& a, const FieldKey& b);

} // namespace frostvdb
