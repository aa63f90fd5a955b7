// Mitsuba 3's `principled` BSDF: the Disney BSDF of Burley 2012, "Physically-Based
// Shading at Disney", and Burley 2015, "Extending the Disney BRDF to a BSDF with
// Integrated Subsurface Scattering", with the parameter set, defaults and lobe
// sampling probabilities of Mitsuba 3's plugin documentation and source.
#pragma once

#include "engine/shading/bsdf.h"
#include "engine/shading/texture.h"

#include <memory>

namespace fg {

// Every parameter but eta is a texture read as a scalar (its luminance) except
// baseColor; a null texture is the parameter left out, which Mitsuba treats as
// 0 and for which it also drops the lobe (spec_trans: no transmission).
struct PrincipledParameters {
    std::shared_ptr<Texture> baseColor;  // default 0.5
    std::shared_ptr<Texture> roughness;  // default 0.5
    std::shared_ptr<Texture> metallic;
    std::shared_ptr<Texture> specTint;
    std::shared_ptr<Texture> anisotropic;
    std::shared_ptr<Texture> sheen;
    std::shared_ptr<Texture> sheenTint;
    std::shared_ptr<Texture> clearcoat;
    std::shared_ptr<Texture> clearcoatGloss;
    std::shared_ptr<Texture> specTrans;
    std::shared_ptr<Texture> flatness;
    // Interior / exterior IOR of the dielectric part; Mitsuba derives it from
    // `specular` with principledEtaFromSpecular unless `eta` is given.
    float eta = 1.5f;
    float mainSpecularSamplingRate = 1.0f;
    float clearcoatSamplingRate = 1.0f;
    float diffuseReflectanceSamplingRate = 1.0f;
};

// Inverse of Schlick's F0 = ((eta - 1) / (eta + 1))^2 with F0 = 0.08 specular
// (Burley 2012, the `specular` parameter); specular = 0.5 gives eta = 1.5.
float principledEtaFromSpecular(float specular);

std::shared_ptr<Bsdf> makePrincipled(PrincipledParameters parameters);

// Mitsuba 3's `principledthin`: a two-sided sheet without volume (Burley 2015's
// thin-surface BSDF). Textures as above; eta is a texture too.
struct PrincipledThinParameters {
    std::shared_ptr<Texture> baseColor;  // default 0.5
    std::shared_ptr<Texture> roughness;  // default 0.5
    std::shared_ptr<Texture> eta;        // default 1.5
    std::shared_ptr<Texture> specTint;
    std::shared_ptr<Texture> anisotropic;
    std::shared_ptr<Texture> sheen;
    std::shared_ptr<Texture> sheenTint;
    std::shared_ptr<Texture> specTrans;
    std::shared_ptr<Texture> flatness;
    std::shared_ptr<Texture> diffTrans;  // 0 to 2, as Mitsuba's
    float specularReflectanceSamplingRate = 1.0f;
    float specularTransmittanceSamplingRate = 1.0f;
    float diffuseReflectanceSamplingRate = 1.0f;
    float diffuseTransmittanceSamplingRate = 1.0f;
};

std::shared_ptr<Bsdf> makePrincipledThin(PrincipledThinParameters parameters);

}  // namespace fg
