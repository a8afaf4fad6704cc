// tsog-stream web player: time evaluation of a TSOG chunk on the GPU.
//
// The engine draws a chunk's SOG part (the base values). This module adds the TSOG part: the
// timeline and temporal images are decoded by the browser (no premultiplication, no colour
// management) into two RGBA8 texture arrays, low bytes and high bytes, one layer per image
// pair, and a gsplatModifyVS chunk evaluates docs/spec.md sections 5-6 per splat at the time t
// given as a uniform. Changing t re-renders the chunk's work buffer on the GPU; nothing is
// computed or uploaded per Gaussian on the CPU. See docs/design/player.md.

export const ATTRIBUTES = ['means', 'scales', 'quats', 'sh0', 'opacity']; // layer order
const TYPES = { FRAME: 0, START_DURATION: 1, CENTER_SCALE: 2 };
const TIME_EPSILON = 1e-9; // tsog_stream.temporal.TIME_EPSILON (timeline units)
const VISIBILITY_THRESHOLD = 1 / 255; // tsog_stream.constants.VISIBILITY_THRESHOLD
const ALPHA_EPS = 1e-6; // tsog_stream.constants.ALPHA_EPS
const U16_MAX = 65535;

/** What a chunk's meta.json says about time: null for a plain SOG chunk. */
export function readLayout(meta) {
    const timeline = meta.timeline;
    if (!timeline) return null;
    if (!Object.values(TYPES).includes(timeline.type)) {
        throw new Error(`meta.json: unknown timeline type ${timeline.type}`);
    }
    const pad = (values) => [0, 1, 2, 3].map((i) => values[i] ?? 0);
    const layers = [{ files: timeline.files, mins: pad(timeline.mins), maxs: pad(timeline.maxs) }];
    const terms = {};
    const channels = {};
    for (const attr of ATTRIBUTES) {
        const entry = meta.temporal?.[attr];
        if (!entry) continue;
        channels[attr] = entry.mins[0].length;
        terms[attr] = entry.mins.map((mins, k) => {
            layers.push({
                files: entry.files.slice(2 * k, 2 * k + 2),
                mins: pad(mins),
                maxs: pad(entry.maxs[k]),
            });
            return layers.length - 1;
        });
    }
    const fps = timeline.type === TYPES.CENTER_SCALE ? null : timeline.fps ?? null;
    return { type: timeline.type, secondsPerUnit: fps ? 1 / fps : 1, layers, terms, channels };
}

/** True when a chunk holds one frame without motion and the stream has a window per frame
 * (a frame sequence stored per frame): the page enables it exactly while t is in that frame
 * (chunksFor picks one window), so evaluating its time on the GPU changes nothing and it is
 * drawn as the plain SOG it also is: no timeline images to decode, no modifier, no uniforms. */
export function isWholeFrame(layout, info, manifest) {
    const fps = manifest.scene.fps;
    const windowPerFrame = fps > 0 && Math.abs(manifest.window_s * fps - 1) < 1e-6;
    const frames = layout.layers[0];
    return windowPerFrame && info.level === 0 && layout.type === TYPES.FRAME
        && Object.keys(layout.terms).length === 0 && frames.mins[0] === frames.maxs[0];
}

/** GLSL of the sum over orders k of layer_k * dt^k for one attribute. */
function polynomial(attr, layerIds) {
    const body = layerIds.map((id) => `\tp *= tsogDt;\n\ts += p * tsogLayer(${id});`).join('\n');
    return `vec4 tsogPoly_${attr}() {\n\tvec4 s = vec4(0.0);\n\tfloat p = 1.0;\n${body}\n\treturn s;\n}\n`;
}

/** GLSL that sets tsogVisible, tsogFactor and tsogDt from layer 0 (docs/spec.md section 5). */
function timelineCode(type) {
    if (type === TYPES.FRAME) {
        return `\tfloat frame = floor(v.x + 0.5);
\ttsogVisible = frame == tsogUnits;
\ttsogDt = tsogT - frame * tsogSpu;`;
    }
    if (type === TYPES.START_DURATION) {
        return `\ttsogVisible = v.x <= tsogUnits && tsogUnits < v.x + v.y;
\ttsogDt = tsogT - v.x * tsogSpu;`;
    }
    return `\tfloat z = (tsogT - v.x) / max(v.y, 1e-30);
\ttsogFactor = v.y > 0.0 ? exp(-0.5 * z * z) : 0.0;
\ttsogVisible = tsogFactor >= ${VISIBILITY_THRESHOLD.toPrecision(9)};
\ttsogDt = tsogT - v.x;`;
}

/** The gsplatModifyVS chunk for one layout (chunks of the same layout share the shader). */
export function modifierGlsl(layout) {
    const { terms, channels } = layout;
    const polys = Object.entries(terms).map(([attr, ids]) => polynomial(attr, ids)).join('');
    const center = terms.means ? '\tcenter += mat3(matrix_model) * tsogPoly_means().xyz;\n' : '';
    // (w, x, y, z) in R, G, B, A; the paper's 3-channel form is (x, y, z), w's coefficient 0
    const quatTerm = channels.quats === 3 ? 'tsogPoly_quats().wxyz' : 'tsogPoly_quats()';
    // opacity is the A channel of a 4-channel sh0 (spec 0.3), or its own attribute (spec 0.2)
    const opacityTerm = terms.opacity
        ? 'tsogPoly_opacity().x'
        : channels.sh0 === 4 ? 'tsogPoly_sh0().a' : null;
    const rotation = terms.quats
        ? `#ifndef GSPLAT_WORKBUFFER_GEOMETRY
\tvec4 q = getRotation() + ${quatTerm};
\tfloat n = length(q);
\tq = n > 0.0 ? q / n : vec4(1.0, 0.0, 0.0, 0.0);
\trotation = quatMul(model_rotation, q.yzwx);
#endif
`
        : '';
    const scale = terms.scales ? '\tscale *= exp(tsogPoly_scales().xyz);\n' : '';
    const colour = terms.sh0 ? '\tcolor.rgb += 0.28209479177387814 * tsogPoly_sh0().rgb;\n' : '';
    const opacity = opacityTerm
        ? `\tfloat a = clamp(color.a, ${ALPHA_EPS}, ${1 - ALPHA_EPS});
\tcolor.a = 1.0 / (1.0 + exp(-(log(a / (1.0 - a)) + ${opacityTerm})));
`
        : '';
    const count = layout.layers.length;
    return `
uniform highp sampler2DArray tsogLo;
uniform highp sampler2DArray tsogHi;
uniform vec4 tsogOffset[${count}];
uniform vec4 tsogStep[${count}];
uniform float tsogT;
uniform float tsogUnits;
uniform float tsogSpu;
bool tsogDone = false;
bool tsogVisible = true;
float tsogFactor = 1.0;
float tsogDt = 0.0;
vec4 tsogLayer(int i) {
\tivec3 p = ivec3(splat.uv, i);
\tvec4 lo = floor(texelFetch(tsogLo, p, 0) * 255.0 + 0.5);
\tvec4 hi = floor(texelFetch(tsogHi, p, 0) * 255.0 + 0.5);
\treturn tsogOffset[i] + tsogStep[i] * (lo + 256.0 * hi);
}
void tsogTimeline() {
\tif (tsogDone) return;
\ttsogDone = true;
\tvec2 v = tsogLayer(0).xy;
${timelineCode(layout.type)}
}
${polys}
void modifySplatCenter(inout vec3 center) {
\ttsogTimeline();
${center}}
void modifySplatRotationScale(vec3 originalCenter, vec3 modifiedCenter, inout vec4 rotation, inout vec3 scale) {
\ttsogTimeline();
${rotation}${scale}\tif (!tsogVisible) scale = vec3(0.0);
}
void modifySplatColor(vec3 center, inout vec4 color) {
\ttsogTimeline();
${colour}${opacity}\tcolor.a = tsogVisible ? color.a * tsogFactor : 0.0;
}
`;
}

/** Uniform values that depend on t (seconds): set on every time change. */
export function timeUniforms(layout, t) {
    const units = t / layout.secondsPerUnit;
    const unitValue = layout.type === TYPES.FRAME ? Math.floor(units + TIME_EPSILON) : units + TIME_EPSILON;
    return { tsogT: t, tsogUnits: unitValue };
}

/** Uniform values fixed for a chunk: per-layer dequantisation and the time unit. */
export function chunkUniforms(layout) {
    const offset = new Float32Array(4 * layout.layers.length);
    const step = new Float32Array(4 * layout.layers.length);
    layout.layers.forEach((layer, i) => {
        for (let c = 0; c < 4; c++) {
            offset[4 * i + c] = layer.mins[c];
            step[4 * i + c] = (layer.maxs[c] - layer.mins[c]) / U16_MAX;
        }
    });
    return { 'tsogOffset[0]': offset, 'tsogStep[0]': step, tsogSpu: layout.secondsPerUnit };
}

/** Decode one lossless WebP to an ImageBitmap with its bytes untouched. */
function decodeImage(name, bytes) {
    const blob = new Blob([bytes], { type: 'image/webp' });
    return createImageBitmap(blob, { premultiplyAlpha: 'none', colorSpaceConversion: 'none' })
        .catch((err) => { throw new Error(`${name}: cannot decode (${err.message ?? err})`); });
}

/** The low-byte and high-byte texture arrays of a chunk, one layer per layout layer. */
export async function createTextures(pc, device, layout, files, label) {
    const bitmaps = await Promise.all(layout.layers.flatMap((layer) => layer.files.map((name) => {
        const bytes = files.get(name);
        if (!bytes) throw new Error(`${label}: ${name} is named in meta.json but missing`);
        return decodeImage(name, bytes);
    })));
    const { width, height } = bitmaps[0];
    if (bitmaps.some((b) => b.width !== width || b.height !== height)) {
        throw new Error(`${label}: timeline and temporal images differ in size`);
    }
    const make = (half) => new pc.Texture(device, {
        name: `${label}-${half === 0 ? 'lo' : 'hi'}`,
        width,
        height,
        format: pc.PIXELFORMAT_RGBA8,
        arrayLength: layout.layers.length,
        mipmaps: false,
        minFilter: pc.FILTER_NEAREST,
        magFilter: pc.FILTER_NEAREST,
        addressU: pc.ADDRESS_CLAMP_TO_EDGE,
        addressV: pc.ADDRESS_CLAMP_TO_EDGE,
        levels: [bitmaps.filter((_, i) => i % 2 === half)],
    });
    return { lo: make(0), hi: make(1) };
}
