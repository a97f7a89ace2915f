// Custom MaterialX BSDF node implementation (target genglsl).
// Prototype: a "neural" BSDF stand-in that evaluates a Lambert lobe whose albedo
// comes from a latent vector (latent.rgb).  A real implementation would run the
// MLP decoder in mx_myneural_eval() and its own importance sampler in
// mx_myneural_sample().
//
// Includes are resolved against the generator's source search path
// (the MaterialX "libraries" folder) -- both are usually already pulled in by
// the lit surface shader, duplicates are skipped by the generator.
#include "libraries/pbrlib/genglsl/lib/mx_closure_type.glsl"
#include "libraries/pbrlib/genglsl/lib/mx_microfacet_specular.glsl"

// ---- "MLP" evaluation: returns f(wi, wo) * cos(wi) ---------------------------
vec3 mx_myneural_eval(vec4 latent, vec3 N, vec3 L, vec3 V)
{
    float NdotL = clamp(dot(N, L), 0.0, 1.0);
    return latent.rgb * NdotL * M_PI_INV;
}

// ---- the BSDF's own importance sampler (placeholder: cosine hemisphere) ---------
// Returns a tangent-space direction and its pdf.
vec3 mx_myneural_sample(vec4 latent, vec2 u, out float pdf)
{
    float phi = 2.0 * M_PI * u.x;
    float cosTheta = sqrt(1.0 - u.y);
    float sinTheta = sqrt(u.y);
    pdf = cosTheta * M_PI_INV;
    return vec3(cos(phi) * sinTheta, sin(phi) * sinTheta, cosTheta);
}

// Signature rule (MaterialX 1.39.5 genglsl): ClosureData first, then the nodedef
// inputs in nodedef order (filename -> sampler2D), then `inout BSDF` last.
void mx_myneural_bsdf(ClosureData closureData, float weight, vec4 latent,
                      sampler2D latent_file, float latent_lod, float explicit_mix,
                      vec2 texcoord, int env_mode, int env_samples, vec3 N,
                      inout BSDF bsdf)
{
    bsdf.throughput = vec3(0.0);     // opaque: nothing passes to layers below
    if (weight < M_FLOAT_EPS)
        return;

    // Explicit-LOD latent fetch straight from a filename input (flip V like the
    // stdlib image node does when fileTextureVerticalFlip is on).
    vec2 uv = vec2(texcoord.x, 1.0 - texcoord.y);
    vec4 latentLod = textureLod(latent_file, uv, latent_lod);
    vec4 z = mix(latent, latentLod, explicit_mix);

    vec3 V = closureData.V;
    N = mx_forward_facing_normal(N, V);

    if (closureData.closureType == CLOSURE_TYPE_REFLECTION)
    {
        // Direct light: L = direction to light; response is multiplied by the
        // light intensity by the surface node.
        bsdf.response = mx_myneural_eval(z, N, closureData.L, V) * closureData.occlusion * weight;
    }
    else if (closureData.closureType == CLOSURE_TYPE_INDIRECT)
    {
        if (env_mode == 0)
        {
            // Library path: prefiltered irradiance map (what oren_nayar does).
            bsdf.response = z.rgb * mx_environment_irradiance(N) * weight;
        }
        else
        {
            // Own estimator: N samples from our sampler, filtered-importance
            // lookup into the radiance map with a pdf-derived mip level.
            mat3 tbn = mx_orthonormal_basis(N);
            int n = max(env_samples, 1);
            vec3 sum = vec3(0.0);
            for (int i = 0; i < n; i++)
            {
                vec2 u = mx_spherical_fibonacci(i, n);
                float pdf;
                vec3 Lt = mx_myneural_sample(z, u, pdf);
                vec3 Lw = mx_matrix_mul(tbn, Lt);   // not `tbn * Lt`: keeps genslang translation correct
                float lod = mx_latlong_compute_lod(Lw, pdf, float($envRadianceMips - 1), n);
                vec3 Li = mx_latlong_map_lookup(Lw, $envMatrix, lod, $envRadiance);
                sum += Li * mx_myneural_eval(z, N, Lw, V) / max(pdf, 1e-6);
            }
            bsdf.response = sum / float(n) * $envLightIntensity * weight;
        }
    }
    // CLOSURE_TYPE_TRANSMISSION / EMISSION: nothing (bsdf="R" node).
}
