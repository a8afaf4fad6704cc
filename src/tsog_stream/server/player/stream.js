// tsog-stream web player: which chunks the playhead needs, fetched ahead and dropped behind.
// Chunks are chosen from the manifest (manifest.js), fetched once each, checked against the
// manifest's SHA-256, handed to the engine as a ".sog" gsplat asset, and given the TSOG time
// evaluation (tsog.js). Works against tsog serve's /v1 API and any static origin alike.
// A stream with quality layers is played adaptively (adapt.js, the Python client's rules):
// the base layer at t first (the first picture), then as many layers as the link keeps up
// with; a frame shows the most layers whose chunks for t have all arrived. A base chunk whose
// SH bands are a chunk of their own (sh_of) is drawn with DC colour, then redrawn with its
// bands once they land: the page rebuilds its SOG with the bands' images (addBands).
// Nothing is taken off the screen before what replaces it can be drawn: while the chunks for
// t are still arriving, the last picture stays (show), and once playback had to wait it goes
// on only when the base of the whole horizon has arrived (playable). The layers kept follow
// the rate the page makes chunks ready (pace.js), not the link's alone.
import { HORIZON_S, REPLAN_S, chooseLayers, layersShown, startupAllowance } from './adapt.js';
import { readCapped } from './check.js';
import { SceneIndex } from './manifest.js';
import { ReadyRate } from './pace.js';
import { readZip, writeZip } from './zip.js';
import { chunkUniforms, createTextures, isWholeFrame, modifierGlsl, readLayout, timeUniforms } from './tsog.js';

const MAX_LOADING = 4;
/** Media seconds fetched ahead while playing, at least (as the Python client's play()): two
 * windows alone were 67 ms with one chunk per frame, and playback waited on every chunk. */
const MIN_HORIZON_S = 1.0;
/** Bytes fetched ahead of t at most (in time order), so a horizon of large chunks stays bounded. */
const AHEAD_BYTES = 64 * 1024 * 1024;
/** Seconds playback waits at most for the chunks ahead once it had to stop (playable). */
const MAX_STALL_S = 10;
/** Gaussians of loaded chunks kept when t no longer needs them (the nearest ahead of t first),
 * so a short looping clip or a scrub back is not fetched and decoded again: with one chunk per
 * frame, every loop refetched the whole clip. About what a laptop GPU draws at once. */
const KEEP_GAUSSIANS = 2_000_000;

/** Hex SHA-256 of an ArrayBuffer, or null where the browser offers no digest (not secure). */
async function sha256(buffer) {
    if (!globalThis.crypto?.subtle) return null;
    const digest = new Uint8Array(await crypto.subtle.digest('SHA-256', buffer));
    return [...digest].map((b) => b.toString(16).padStart(2, '0')).join('');
}

/** Chunk scheduling for one scene: loads what t needs (and, playing, what follows), drops the rest. */
export class ChunkStream {
    /**
     * @param {object} pc the PlayCanvas module
     * @param {object} app the running pc.Application
     * @param {object} parent the entity chunks are drawn under (it turns the scene upright)
     * @param {object} manifest the parsed scene manifest
     * @param {(chunk: object) => string} chunkUrl where a chunk's bytes are
     * @param {string[]} fetchLog every URL fetched is appended here (for the overlay and tests)
     */
    constructor(pc, app, parent, manifest, chunkUrl, fetchLog) {
        this.pc = pc;
        this.app = app;
        this.index = new SceneIndex(manifest);
        this.chunkUrl = chunkUrl;
        this.fetchLog = fetchLog;
        this.horizon = Math.max(2 * manifest.window_s, MIN_HORIZON_S);
        this.keepGaussians = KEEP_GAUSSIANS;
        this.root = new pc.Entity('tsog-chunks');
        parent.addChild(this.root);
        this.chunks = new Map(); // id -> {info, state, entity, layout, textures, abort}
        // host id -> id of the chunk holding its SH bands beyond DC
        this.bandsOf = new Map(manifest.chunks.filter((c) => c.sh_of != null).map((c) => [c.sh_of, c.id]));
        this.wanted = []; // ids in load priority: needed at t first, then ahead of t
        this.shown = new Set(); // ids drawn at t (exactly chunks_for(t))
        this.planned = null; // [t, playing] the plan was made for
        this.bytes = 0;
        this.error = null;
        this.bufferedFor = null; // {version, ranges}: buffered() recomputed when chunks change
        this.throughput = new ReadyRate();
        this.opened = this.throughput.clock();
        this.stalled = true; // playback waits for the chunks ahead (see playable), at first too
        this.stalledAt = null;
        this.aheadBase = []; // the base chunks of the horizon the plan loads, for playable
        // adaptation: when the first picture came, when playback started, the layers fetched
        this.adapt = { firstAt: null, startedAt: null, deadline: null, level: 0, replannedAt: 0 };
        this.shownLayers = 0;
        this.changes = 0; // bumped whenever what is drawn changes (the page redraws on it)
        if (this.index.layerCount > 1) this.horizon = Math.max(this.horizon, HORIZON_S);
    }

    /** True when chunk `id` has arrived (or failed: playback must not hang on it). */
    arrived(id) {
        const c = this.chunks.get(id);
        return c !== undefined && (c.state === 'ready' || c.state === 'failed');
    }

    /** Layers to fetch for t: the base before the first picture, every layer when paused
     * (a still at full quality), else the adaptation's choice. */
    layersFor(playing) {
        if (this.adapt.firstAt === null) return 1;
        return playing ? Math.max(this.adapt.level, 1) : this.index.layerCount;
    }

    /** While playing, revisit the layers kept every REPLAN_S (chooseLayers). */
    replan(t, playing) {
        const now = this.throughput.clock();
        if (!playing || this.adapt.startedAt === null || now - this.adapt.replannedAt < REPLAN_S) return;
        this.adapt.replannedAt = now;
        const level = chooseLayers(this.index, t, this.index.manifest.scene.end_s, {
            speed: 1, rate: this.throughput.estimate, have: (id) => this.arrived(id),
            current: this.adapt.level, allowance: 0,
        });
        if (level !== this.adapt.level) {
            this.adapt.level = level;
            this.planned = null;
        }
    }

    /** Called every frame: plan for t when it changed, start loads, drop, show, set time. */
    update(t, playing, loop = false) {
        this.replan(t, playing);
        if (!this.planned || this.planned[0] !== t || this.planned[1] !== playing || this.planned[2] !== loop) {
            this.plan(t, playing, loop);
        }
        this.loadWanted();
        this.show(t);
    }

    /** The intervals of media time the horizon covers from t: [t, t + horizon] clipped to the
     * scene, and, looping, its continuation from the scene's start. */
    aheadIntervals(t, loop) {
        const { start_s: start, end_s: end } = this.index.manifest.scene;
        const out = [[t, Math.min(t + this.horizon, end)]];
        const over = t + this.horizon - end;
        if (loop && over > 0) out.push([start, Math.min(start + over, t)]);
        return out;
    }

    /** What t needs (its base first), then (playing) what the horizon needs, base layers
     * first, enhancements once the horizon's base is in (one layer beyond the kept ones once
     * those are in), in time order and within
     * AHEAD_BYTES; drop the rest (see dropUnwanted). */
    plan(t, playing, loop = false) {
        this.planned = [t, playing, loop];
        const layers = this.layersFor(playing);
        const byLayer = (x, y) => (x.layer ?? 0) - (y.layer ?? 0);
        const needed = this.index.chunksFor(t, layers).sort(byLayer);
        const intervals = this.aheadIntervals(t, loop);
        const ahead = [];
        if (playing) {
            const spans = intervals.map(([a, b]) => this.index.chunksForInterval(a, b)); // every layer's
            const inFor = (n) => spans.every((span) => span.every((c) => (c.layer ?? 0) >= n || this.arrived(c.id)));
            // the base first; the layers kept once it is in; one more once those are in too
            // (a link with room to spare fetches the next layer before the plan counts on it)
            const top = !inFor(1) ? 1 : inFor(layers) ? Math.min(layers + 1, this.index.layerCount) : layers;
            const part = [];
            for (let layer = 0; layer < top; layer++) {
                for (const span of spans) {
                    const mine = span.filter((c) => (c.layer ?? 0) === layer);
                    part.push(...mine.sort((x, y) => x.start_s - y.start_s));
                }
            }
            let bytes = 0;
            for (const c of part) {
                bytes += c.length;
                if (bytes > AHEAD_BYTES) break;
                ahead.push(c);
            }
        }
        this.wanted = [...new Set([...needed, ...ahead].map((c) => c.id))];
        this.aheadBase = ahead.filter((c) => (c.layer ?? 0) === 0);
        this.shown = new Set(this.index.chunksFor(t, 1).map((c) => c.id));
        for (const id of this.wanted) {
            if (!this.chunks.has(id)) this.chunks.set(id, { info: this.index.manifest.chunks[id], state: 'queued' });
        }
        this.dropUnwanted(t, loop);
    }

    /** Drop what t and the horizon do not want, except the chunks on screen and chunks loaded
     * or loading within keepGaussians, kept nearest first (looping, nearest ahead of t; else
     * nearest in time): a load is aborted only when over that budget. */
    dropUnwanted(t, loop) {
        const wanted = new Set(this.wanted);
        const spare = [];
        for (const [id, c] of this.chunks) {
            if (wanted.has(id) || c.entity?.enabled) continue; // the picture on screen stays
            if (c.state === 'ready' || c.state === 'loading') spare.push(c);
            else this.forget(c);
        }
        const gaussians = (c) => (c?.info.sh_of == null ? c?.info.count ?? 0 : 0); // bands hold none
        let kept = [...wanted].reduce((n, id) => n + gaussians(this.chunks.get(id)), 0);
        spare.sort((a, b) => this.distance(a, t, loop) - this.distance(b, t, loop));
        for (const c of spare) {
            kept += gaussians(c);
            if (kept > this.keepGaussians) this.forget(c);
        }
    }

    /** Media seconds from t until the chunk is needed (looping: going forward round the clip). */
    distance(c, t, loop) {
        if (c.info.start_s <= t && t <= c.info.end_s) return 0;
        const { start_s: start, end_s: end } = this.index.manifest.scene;
        if (loop) return c.info.start_s > t ? c.info.start_s - t : end - t + (c.info.start_s - start);
        return c.info.start_s > t ? c.info.start_s - t : t - c.info.end_s;
    }

    /** Unload a chunk and stop tracking it. */
    forget(c) {
        this.unload(c);
        this.chunks.delete(c.info.id);
    }

    /** Start loading wanted chunks in priority order, at most MAX_LOADING at a time. */
    loadWanted() {
        let loading = [...this.chunks.values()].filter((c) => c.state === 'loading').length;
        for (const id of this.wanted) {
            if (loading >= MAX_LOADING) return;
            const c = this.chunks.get(id);
            if (c?.state === 'queued') {
                loading += 1;
                this.load(c).catch((err) => {
                    if (c.state === 'dropped') return;
                    c.state = 'failed';
                    this.error = `chunk ${c.info.id}: ${err.message ?? err}`;
                    console.error(this.error);
                }).finally(() => this.loadWanted()); // the next at once, not a frame later
            }
        }
    }

    /** Fetch, check and decode one chunk, then attach it to an entity with its time shader.
     * The rate counts the whole of it (on a fast link the page's decoding is the limit). */
    async load(c) {
        c.state = 'loading';
        c.abort = new AbortController();
        this.throughput.started();
        let made = 0;
        try {
            await this.fetchAndDecode(c);
            made = c.state === 'ready' ? c.info.length : 0;
        } finally {
            this.throughput.finished(made);
        }
    }

    /** The steps of load: fetch, length and SHA-256 checks, unzip, textures, engine asset. */
    async fetchAndDecode(c) {
        const pc = this.pc;
        const url = this.chunkUrl(c.info);
        this.fetchLog.push(url);
        const response = await fetch(url, { signal: c.abort.signal });
        if (!response.ok) throw new Error(`HTTP ${response.status}`);
        const buffer = await readCapped(response, c.info.length, `more than the manifest's ${c.info.length} bytes`);
        this.bytes += buffer.byteLength;
        if (buffer.byteLength !== c.info.length) {
            throw new Error(`${buffer.byteLength} bytes, the manifest says ${c.info.length}`);
        }
        const digest = await sha256(buffer);
        if (digest !== null && digest !== c.info.sha256) throw new Error('SHA-256 differs from the manifest');
        const files = await readZip(buffer);
        const meta = JSON.parse(new TextDecoder().decode(files.get('meta.json')));
        if (c.info.sh_of != null || this.bandsOf.has(c.info.id)) Object.assign(c, { files, meta });
        if (c.info.sh_of != null) { // SH bands of another chunk: drawn with it, nothing alone
            c.state = 'ready';
            return this.joinBands(c.info.sh_of);
        }
        c.layout = readLayout(meta);
        if (c.layout && isWholeFrame(c.layout, c.info, this.index.manifest)) c.layout = null;
        if (c.layout) {
            c.textures = await createTextures(pc, this.app.graphicsDevice, c.layout, files, `chunk-${c.info.id}`);
        }
        if (c.state === 'dropped') return this.release(c);
        c.asset = await this.loadAsset(`chunk-${c.info.id}`, url, buffer);
        if (c.state === 'dropped') return this.release(c);
        c.entity = this.attach(c, c.asset);
        c.state = 'ready';
        return this.joinBands(c.info.id);
    }

    /** Start addBands for a host (a failure there is reported, the host stays drawn). */
    joinBands(hostId) {
        this.addBands(hostId).catch((err) => {
            this.error = `SH bands of chunk ${hostId}: ${err.message ?? err}`;
            console.error(this.error);
        });
    }

    /** A gsplat asset of a chunk's SOG bytes, loaded by the engine. */
    async loadAsset(name, url, contents) {
        const filename = url.split('?')[0].split('/').pop();
        const asset = new this.pc.Asset(name, 'gsplat', { url, filename, contents });
        await new Promise((resolve, reject) => {
            asset.once('load', resolve);
            asset.once('error', (err) => reject(new Error(String(err))));
            this.app.assets.add(asset);
            this.app.assets.load(asset);
        });
        return asset;
    }

    /** Once a base chunk and its SH-band chunk have both arrived, redraw the base with its
     * bands: its SOG rebuilt with the bands' shN images and meta (texel for texel the same
     * Gaussians), swapped in for the DC-only one. */
    async addBands(hostId) {
        const host = this.chunks.get(hostId);
        const bands = this.chunks.get(this.bandsOf.get(hostId));
        if (host?.state !== 'ready' || bands?.state !== 'ready' || host.withBands) return;
        host.withBands = true;
        const files = new Map([...host.files].filter(([name]) => name !== 'meta.json'));
        for (const name of bands.meta.shN.files) files.set(name, bands.files.get(name));
        const meta = { ...host.meta, shN: bands.meta.shN };
        files.set('meta.json', new TextEncoder().encode(JSON.stringify(meta)));
        const url = `${this.chunkUrl(host.info).split('?')[0]}?sh`; // its own URL, the same file name
        const asset = await this.loadAsset(`chunk-${hostId}-sh`, url, writeZip(files));
        if (host.state !== 'ready') {
            this.app.assets.remove(asset);
            asset.unload();
            return;
        }
        const old = { entity: host.entity, asset: host.asset };
        Object.assign(host, { asset, entity: this.attach(host, asset), files: null, meta: null });
        host.entity.enabled = old.entity.enabled;
        old.entity.destroy();
        this.app.assets.remove(old.asset);
        old.asset.unload();
        this.changes += 1;
    }

    /** An entity drawing the chunk, with the TSOG modifier and its uniforms when it has a timeline. */
    attach(c, asset) {
        const entity = new this.pc.Entity(`chunk-${c.info.id}`);
        entity.enabled = false;
        entity.addComponent('gsplat', { asset });
        if (c.layout) {
            const gsplat = entity.gsplat;
            gsplat.setWorkBufferModifier({ glsl: modifierGlsl(c.layout) });
            gsplat.setParameter('tsogLo', c.textures.lo);
            gsplat.setParameter('tsogHi', c.textures.hi);
            for (const [name, value] of Object.entries(chunkUniforms(c.layout))) gsplat.setParameter(name, value);
            c.time = null;
        }
        this.root.addChild(entity);
        return entity;
    }

    /** Enable exactly the chunks of chunks_for(t) with the most layers that have all arrived
     * and give them t (only when it changed). While t's base is still arriving, the picture on
     * screen stays as it is (the base's chunks that are in are shown only when nothing is). */
    show(t) {
        this.shownLayers = layersShown(this.index, t, (id) => this.arrived(id));
        const onScreen = [...this.chunks].filter(([, c]) => c.state === 'ready' && c.entity?.enabled);
        if (this.shownLayers === 0 && onScreen.length > 0) {
            this.shown = new Set(onScreen.map(([id]) => id));
            return;
        }
        this.shown = new Set(this.index.chunksFor(t, Math.max(this.shownLayers, 1)).map((c) => c.id));
        for (const [id, c] of this.chunks) {
            if (c.state !== 'ready' || !c.entity) continue; // SH bands are drawn with their host
            const on = this.shown.has(id);
            if (c.entity.enabled !== on) {
                c.entity.enabled = on;
                this.changes += 1;
            }
            if (on && c.layout && c.time !== t) {
                for (const [name, value] of Object.entries(timeUniforms(c.layout, t))) {
                    c.entity.gsplat.setParameter(name, value);
                }
                c.time = t;
                this.changes += 1;
            }
        }
    }

    /** Stop a chunk's load or free what it holds. */
    unload(c) {
        const was = c.state;
        c.state = 'dropped';
        if (was === 'loading') c.abort?.abort();
        else this.release(c);
    }

    /** Free the entity, the asset and the textures of a chunk. */
    release(c) {
        if (c.entity) this.changes += 1;
        c.entity?.destroy();
        if (c.asset) {
            this.app.assets.remove(c.asset);
            c.asset.unload();
        }
        c.textures?.lo.destroy();
        c.textures?.hi.destroy();
        c.entity = c.asset = c.textures = null;
    }

    /** True when t can be drawn: its base layer has arrived (chunks that failed count, so
     * playback does not hang) and, the first time, the startup wait is over: the layers the
     * link keeps up with for t (or the allowance after the first picture, whichever first). */
    covered(t) {
        if (!this.index.chunksFor(t, 1).every((c) => this.arrived(c.id))) return false;
        const adapt = this.adapt;
        const now = this.throughput.clock();
        if (adapt.firstAt === null) {
            adapt.firstAt = now;
            const allowance = startupAllowance(now - this.opened);
            adapt.level = chooseLayers(this.index, t, this.index.manifest.scene.end_s, {
                speed: 1, rate: this.throughput.estimate, have: (id) => this.arrived(id), current: 0, allowance,
            });
            adapt.deadline = now + allowance;
            this.planned = null;
        }
        if (adapt.startedAt === null) {
            const ready = this.index.chunksFor(t, adapt.level).every((c) => this.arrived(c.id));
            if (!ready && now < adapt.deadline) return false;
            adapt.startedAt = now;
            adapt.replannedAt = now;
        }
        return true;
    }

    /** True when playback may advance from t: t can be drawn (covered) and, once it had to
     * wait (and at the start), the horizon's base has arrived or it waited MAX_STALL_S: a
     * playhead that caught up with the loads waits for a stretch it can play through, not for
     * the next chunk alone (one frame, a wait, one frame: a stutter at a fraction of 1x). */
    playable(t, playing) {
        const now = this.throughput.clock();
        if (!this.covered(t)) {
            this.stalled = true;
            return false;
        }
        if (!this.stalled || !playing) return true;
        this.stalledAt ??= now;
        const filled = this.aheadBase.every((c) => this.arrived(c.id));
        if (!filled && now - this.stalledAt < MAX_STALL_S) return false;
        this.stalled = false;
        this.stalledAt = null;
        return true;
    }

    /** Time ranges [start, end] whose every needed chunk is loaded, merged: between two
     * consecutive chunk or window edges the needed set is constant, so one probe each. */
    buffered() {
        const version = [...this.chunks.values()].filter((c) => c.state === 'ready').map((c) => c.info.id).join();
        if (this.bufferedFor?.version === version) return this.bufferedFor.ranges;
        const m = this.index.manifest;
        const edges = new Set([m.scene.start_s, m.scene.end_s]);
        for (let w = 1; w < this.index.windows; w++) edges.add(m.scene.start_s + w * m.window_s);
        for (const c of m.chunks) edges.add(c.start_s).add(c.end_s);
        const sorted = [...edges].filter((e) => e >= m.scene.start_s && e <= m.scene.end_s).sort((a, b) => a - b);
        const ranges = [];
        for (let i = 1; i < sorted.length; i++) {
            const [a, b] = [sorted[i - 1], sorted[i]];
            const ready = this.index.chunksFor((a + b) / 2).every((c) => this.chunks.get(c.id)?.state === 'ready');
            if (!ready) continue;
            const last = ranges[ranges.length - 1];
            if (last && last[1] === a) last[1] = b;
            else ranges.push([a, b]);
        }
        this.bufferedFor = { version, ranges };
        return ranges;
    }

    /** A live stream's newer index (spec 8.8): the chunks already loaded stay (a published
     * chunk never changes), the next plan sees the new ones. */
    setManifest(manifest) {
        this.index = new SceneIndex(manifest);
        this.bandsOf = new Map(manifest.chunks.filter((c) => c.sh_of != null).map((c) => [c.sh_of, c.id]));
        this.planned = null;
        this.bufferedFor = null;
        this.changes += 1;
    }

    /** Counts for the overlay and the tests. */
    stats() {
        const all = [...this.chunks.values()];
        const loaded = all.filter((c) => c.state === 'ready').map((c) => c.info.id);
        return {
            known: all.length,
            ready: loaded.length,
            loaded,
            loading: all.filter((c) => c.state === 'loading').length,
            failed: all.filter((c) => c.state === 'failed').length,
            shown: [...this.shown],
            error: this.error,
            bytes: this.bytes,
            layers: this.shownLayers,
            layerCount: this.index.layerCount,
            level: this.adapt.level,
            firstPictureS: this.adapt.firstAt === null ? null : this.adapt.firstAt - this.opened,
            startupS: this.adapt.startedAt === null ? null : this.adapt.startedAt - this.opened,
            throughput: this.throughput.estimate,
        };
    }
}
