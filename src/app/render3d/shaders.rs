//! The GLSL of the point program and of the two composite passes.

// Colours as bytes bound as integer attributes (three-d binds u8 that way), hence uvec4.
pub(super) const POINT_VS: &str = r#"
uniform mat4 mvp;
uniform mat4 model;
uniform vec3 eye;
uniform vec4 tint;
uniform float point_size;
uniform int shade;
in vec3 position;
in uvec4 color;
in vec3 normal;
out vec4 v_color;
void main() {
    gl_Position = mvp * vec4(position, 1.0);
    gl_PointSize = point_size;
    vec4 c = vec4(color) / 255.0 * tint;
    if (shade == 1) {
        vec3 wp = (model * vec4(position, 1.0)).xyz;
        vec3 n = mat3(model) * normal;
        float len = length(n);
        float l = len > 1e-6 ? abs(dot(n / len, normalize(eye - wp))) : 1.0;
        c.rgb *= 0.3 + 0.7 * l;
    }
    v_color = c;
}
"#;

pub(super) const POINT_FS: &str = r#"
in vec4 v_color;
out vec4 out_color;
void main() {
    out_color = v_color;
}
"#;

pub(super) const QUAD_VS: &str = r#"
in vec2 corner;
out vec2 uv;
void main() {
    uv = corner * 0.5 + 0.5;
    gl_Position = vec4(corner, 0.0, 1.0);
}
"#;

// The offscreen points as they are (no depth cue, or normal shading done per point).
pub(super) const COPY_FS: &str = r#"
uniform sampler2D color_tex;
uniform sampler2D depth_tex;
in vec2 uv;
out vec4 out_color;
void main() {
    out_color = vec4(texture(color_tex, uv).rgb, 1.0);
    gl_FragDepth = texture(depth_tex, uv).r;
}
"#;

// Eye-dome lighting (Boucheny 2009): the response is how much nearer, in log2 of the linear
// depth, the 8 neighbours at `radius` pixels are; background neighbours count as no nearer.
pub(super) const EDL_FS: &str = r#"
uniform sampler2D color_tex;
uniform sampler2D depth_tex;
uniform vec2 texel;
uniform float near;
uniform float far;
uniform float strength;
uniform vec4 background;
in vec2 uv;
out vec4 out_color;
float logz(float d) {
    return log2(near * far / (far - d * (far - near)));
}
void main() {
    float d = texture(depth_tex, uv).r;
    if (d >= 1.0) {
        out_color = background;
        gl_FragDepth = 1.0;
        return;
    }
    float l = logz(d);
    float sum = 0.0;
    for (int i = 0; i < 8; i++) {
        float a = float(i) * 0.785398;
        vec2 o = vec2(cos(a), sin(a)) * 1.5 * texel;
        float dn = texture(depth_tex, uv + o).r;
        if (dn < 1.0) {
            sum += max(0.0, l - logz(dn));
        }
    }
    float shade = exp(-sum * 60.0 * strength);
    out_color = vec4(texture(color_tex, uv).rgb * shade, 1.0);
    gl_FragDepth = d;
}
"#;
