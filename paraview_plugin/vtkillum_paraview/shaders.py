"""GLSL for the illuminated volume in ParaView's render view (VTK 9.2's GPU ray caster).

Three replacements of the fragment shader of ``vtkOpenGLGPUVolumeRayCastMapper``
(single-component scalars), made through the volume's ``vtkShaderProperty``:

``//VTK::CustomUniforms::Dec`` -> :data:`UNIFORMS_DEC`
    Replaced *before* VTK fills it (``replaceFirst``), so VTK's own declarations of
    the custom uniforms are not written and this block declares them itself. That
    is what lets a custom uniform be a ``sampler3D``: ``vtkUniforms`` has no sampler
    type, but its ``SetUniformi`` (``glUniform1i``) is exactly how a sampler is
    pointed at a texture unit.
``//VTK::Shading::Dec`` -> :data:`SHADING_DEC`
    Phase function, normals, geometry (texture <-> world).
``//VTK::ComputeVolumetricShadow::Dec`` -> :data:`LATE_DEC` (the tag kept)
    What needs ``computeOpacity``, declared after ``//VTK::Shading::Dec``: sigma_t and
    the transmittance towards a light, marched exactly over the first ``near`` (two
    cells of the light grid) and read from the grid beyond, as
    :func:`vtkillum.core.raycast.cached_transmittance` does.
``//VTK::Shading::Impl`` -> :data:`SHADING_IMPL`
    The composite step, in the project's convention (``DESIGN.md``)::

        alpha  = computeOpacity(s)         (VTK's table: 1 - exp(-sigma_t * step), display's u)
        L      = sum_l p_HG(cos theta_l) T_l(x) E_l(x) + phi_s(x) / (4 pi)
        C     += (1 - A) alpha * albedo * Exposure * color(s) * L * S(x)
        A     += (1 - A) alpha

    with ``cos theta_l = dot(unit vector towards light l, ray direction camera ->
    sample)``, ``E_l`` the irradiance (directional) or ``I / max(d, r)^2`` (point, ``r``
    its source radius, 0: half the smallest spacing), ``S`` the
    Phong factor ``ka + kd mean|n.l| + ks mean max(n.h, 0)^p`` when the display's
    *Shade* is on (1 otherwise), ``n`` the two-sided normal of the scalar gradient
    (central differences one voxel apart; ``S = ka + kd`` where it vanishes).
    ``T_l`` and ``phi_s`` are sampled trilinearly from 3D textures on the data's grid
    (the sample's own texture coordinate), so the lighting is as smooth as the data.
    Mode 1 (a method with only an isotropic ``fluence``): ``L = phi / (4 pi)``.

Geometry is in world coordinates: the CPU passes the texture -> world matrix
(origin, spacing, direction matrix and the display's transform), the light list
and the camera, so the shader needs none of VTK's internal matrices.
"""

#: Lights the shader takes (two RGBA transmittance textures).
MAX_LIGHTS = 8
#: Floats per light in ``il_lights``: type, x, y, z, r, g, b, source radius.
LIGHT_STRIDE = 8

UNIFORMS_DEC = """
// vtkillum (paraview_plugin/vtkillum_paraview/shaders.py): custom uniforms, declared here
uniform sampler3D il_T0;            // transmittance towards lights 0..3
uniform sampler3D il_T1;            // transmittance towards lights 4..7
uniform sampler3D il_S;             // scattered fluence phi_s (mode 0) or fluence (mode 1), RGB
uniform int il_numLights;
uniform int il_mode;
uniform float il_lights[%(nfloats)d];  // per light: type, x, y, z, r, g, b, radius (world)
uniform float il_texToWorld[16];    // row-major affine: texture coordinate -> world
uniform float il_worldToTex[16];    // its inverse
uniform float il_normalMatrix[9];   // row-major: local gradient (index axes) -> world normal
uniform vec4 il_shading;            // ka, kd, ks, shininess
uniform vec4 il_params;             // albedo * exposure, g, near (world), parallel (0/1)
uniform vec3 il_camera;             // camera position, or direction of projection if parallel
uniform vec3 il_texel;              // one voxel in texture coordinates (1 / dims)
uniform vec3 il_spacing;            // data spacing (world units per voxel along each axis)
""" % {"nfloats": MAX_LIGHTS * LIGHT_STRIDE}

SHADING_DEC = """//VTK::Shading::Dec
// vtkillum: illumination per sample (paraview_plugin/vtkillum_paraview/shaders.py)
const float IL_INV_4PI = 0.07957747154594767;
const float IL_GRADIENT_EPS = %(gradient_eps).9g;

vec3 il_world(vec3 tc)
{
  vec4 p = vec4(tc, 1.0);
  return vec3(
    dot(vec4(il_texToWorld[0], il_texToWorld[1], il_texToWorld[2], il_texToWorld[3]), p),
    dot(vec4(il_texToWorld[4], il_texToWorld[5], il_texToWorld[6], il_texToWorld[7]), p),
    dot(vec4(il_texToWorld[8], il_texToWorld[9], il_texToWorld[10], il_texToWorld[11]), p));
}

vec3 il_tex(vec3 pw, float w)  // world -> texture coordinate (w = 1: point, 0: direction)
{
  vec4 p = vec4(pw, w);
  return vec3(
    dot(vec4(il_worldToTex[0], il_worldToTex[1], il_worldToTex[2], il_worldToTex[3]), p),
    dot(vec4(il_worldToTex[4], il_worldToTex[5], il_worldToTex[6], il_worldToTex[7]), p),
    dot(vec4(il_worldToTex[8], il_worldToTex[9], il_worldToTex[10], il_worldToTex[11]), p));
}

// Henyey-Greenstein, normalised over the sphere; c = cos(light travel, to camera).
float il_hg(float c, float g)
{
  float d = 1.0 + g * g - 2.0 * g * c;
  return IL_INV_4PI * (1.0 - g * g) / (d * sqrt(d));
}

float il_scalar(vec3 tc)
{
  return texture3D(in_volume[0], tc).r * in_volume_scale[0].r + in_volume_bias[0].r;
}

// Distance (world) from texture point t along texture direction wt to the data's box
// (the grid points span [0.5 / n, 1 - 0.5 / n]).
float il_boxExit(vec3 t, vec3 wt)
{
  vec3 lo = 0.5 * il_texel;
  vec3 hi = vec3(1.0) - 0.5 * il_texel;
  float t1 = 1.0e30;
  for (int a = 0; a < 3; ++a)
  {
    if (abs(wt[a]) >= 1.0e-12)
    {
      t1 = min(t1, max((lo[a] - t[a]) / wt[a], (hi[a] - t[a]) / wt[a]));
    }
  }
  return t1;
}


float il_gridT(int i, vec3 tc)
{
  vec4 a = texture3D(il_T0, tc);
  vec4 b = texture3D(il_T1, tc);
  return i < 4 ? a[min(i, 3)] : b[max(i - 4, 0)];
}

// Two-sided normal (world) facing the camera direction v_to_cam; false where the gradient
// vanishes.
bool il_normal(vec3 tc, vec3 v_to_cam, out vec3 n)
{
  vec3 g = vec3(
    il_scalar(tc + vec3(il_texel.x, 0.0, 0.0)) - il_scalar(tc - vec3(il_texel.x, 0.0, 0.0)),
    il_scalar(tc + vec3(0.0, il_texel.y, 0.0)) - il_scalar(tc - vec3(0.0, il_texel.y, 0.0)),
    il_scalar(tc + vec3(0.0, 0.0, il_texel.z)) - il_scalar(tc - vec3(0.0, 0.0, il_texel.z))
  ) / (2.0 * il_spacing);
  if (length(g) <= IL_GRADIENT_EPS / min(il_spacing.x, min(il_spacing.y, il_spacing.z)))
  {
    return false;
  }
  n = normalize(vec3(
    dot(vec3(il_normalMatrix[0], il_normalMatrix[1], il_normalMatrix[2]), g),
    dot(vec3(il_normalMatrix[3], il_normalMatrix[4], il_normalMatrix[5]), g),
    dot(vec3(il_normalMatrix[6], il_normalMatrix[7], il_normalMatrix[8]), g)));
  if (dot(n, v_to_cam) < 0.0)
  {
    n = -n;
  }
  return true;
}
""" % {"gradient_eps": 1.0e-5}

LATE_DEC = """//VTK::ComputeVolumetricShadow::Dec
// vtkillum: helpers that need computeOpacity (declared after //VTK::Shading::Dec in VTK 9.2)
// sigma_t of a normalised scalar, from VTK's opacity table (corrected for the ray step).
float il_sigmaT(float s)
{
  float a = computeOpacity(vec4(s));
  return -log(max(1.0 - a, 1.0e-7)) / in_sampleDistance;
}

// T_l: exact over the first `near` towards the light, then the grid one or two cells on
// (as vtkillum.core.raycast.cached_transmittance: interpolating the grid across a sharp
// surface would mix points in front of and behind it).
float il_nearMarch(vec3 tc, vec3 wt, float len)
{
  len = min(len, il_boxExit(tc, wt));
  if (len <= 0.0)
  {
    return 1.0;
  }
  int n = int(ceil(len / in_sampleDistance));
  float h = len / float(n);
  float tau = 0.0;
  for (int k = 0; k < n; ++k)
  {
    tau += il_sigmaT(il_scalar(tc + ((float(k) + 0.5) * h) * wt));
  }
  return exp(-tau * h);
}

float il_cachedT(int i, vec3 tc, vec3 l_world, float dist)
{
  float near = min(il_params.z, dist);
  vec3 wt = il_tex(l_world, 0.0);  // texture units per world unit along the light
  float t = near > 0.0 ? il_nearMarch(tc, wt, near) : 1.0;
  vec3 q = tc + near * wt;
  vec3 lo = 0.5 * il_texel;
  vec3 hi = vec3(1.0) - 0.5 * il_texel;
  if (near < dist && all(greaterThanEqual(q, lo)) && all(lessThanEqual(q, hi)))
  {
    t *= il_gridT(i, q);
  }
  return t;
}
"""

SHADING_IMPL = """
    if (!g_skip)
    {
      vec4 il_s = texture3D(in_volume[0], g_dataPos);
      il_s.r = il_s.r * in_volume_scale[0].r + in_volume_bias[0].r;
      il_s = vec4(il_s.r);
      float il_alpha = computeOpacity(il_s);
      if (il_alpha > 0.0)
      {
        vec3 il_color = texture2D(in_colorTransferFunc_0[0], vec2(il_s.w, 0.0)).rgb;
        vec3 il_pw = il_world(g_dataPos);
        // ray direction camera -> sample, and its opposite (towards the camera)
        vec3 il_ray = il_params.w > 0.5 ? normalize(il_camera) : normalize(il_pw - il_camera);
        vec3 il_v = -il_ray;
        float ka = il_shading.x;
        float kd = il_shading.y;
        float ks = il_shading.z;
        bool il_shade = kd > 0.0 || ks > 0.0;
        vec3 il_n = vec3(0.0);
        bool il_hasNormal = il_shade && il_normal(g_dataPos, il_v, il_n);
        float il_diff = 0.0;
        float il_spec = 0.0;
        vec3 il_L = vec3(0.0);
        for (int i = 0; i < il_numLights; ++i)
        {
          int b = %(stride)d * i;
          vec3 xyz = vec3(il_lights[b + 1], il_lights[b + 2], il_lights[b + 3]);
          vec3 rgb = vec3(il_lights[b + 4], il_lights[b + 5], il_lights[b + 6]);
          vec3 il_l;   // unit vector towards the light
          vec3 il_E;   // irradiance at the sample
          float il_dist = 1.0e30;
          if (il_lights[b] < 0.5)
          {
            il_l = xyz;
            il_E = rgb;
          }
          else
          {
            // a small sphere of the light's radius: I / max(d, r)^2 (vtkillum.core.lights)
            vec3 d = xyz - il_pw;
            il_dist = sqrt(dot(d, d));
            float r2 = max(dot(d, d), il_lights[b + 7] * il_lights[b + 7]);
            il_l = d / max(il_dist, 1e-30);
            il_E = rgb / r2;
          }
          if (il_mode == 0)
          {
            float il_T = il_cachedT(i, g_dataPos, il_l, il_dist);
            il_L += il_hg(dot(il_l, il_ray), il_params.y) * il_T * il_E;
          }
          if (il_hasNormal)
          {
            il_diff += abs(dot(il_n, il_l));
            vec3 h = il_l + il_v;
            float hl = length(h);
            if (hl > 0.0)
            {
              il_spec += pow(max(dot(il_n, h / hl), 0.0), il_shading.w);
            }
          }
        }
        il_L += texture3D(il_S, g_dataPos).rgb * IL_INV_4PI;
        float il_phong = 1.0;
        if (il_shade)
        {
          il_phong = il_hasNormal && il_numLights > 0 ?
            ka + (kd * il_diff + ks * il_spec) / float(il_numLights) : ka + kd;
        }
        vec3 il_src = il_params.x * il_phong * il_color * il_L;
        g_fragColor.rgb += (1.0 - g_fragColor.a) * il_alpha * il_src;
        g_fragColor.a += (1.0 - g_fragColor.a) * il_alpha;
      }
    }
""" % {"stride": LIGHT_STRIDE}
