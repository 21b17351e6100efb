//! Training from WebDataset shards by streaming: the epoch order (shards dealt to streams, each
//! through a shuffle buffer) against a plain simulation, and the loader's samples, read from
//! real shards sequentially, against the same positions recomputed from scratch (a resume) and
//! decoded on another number of threads, and against random access.

use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;

use crestereo_train::augment::{AugmentConfig, augment_random};
use crestereo_train::config::{DatasetEntry, StreamSettings};
use crestereo_train::data::stream_order::StreamLayout;
use crestereo_train::data::{Loader, MixedSource, Planner, epoch_seed};
use crestereo_train::synthetic::write_crestereo_dataset;
use rand::Rng;
use stereo_io::{ReadOptions, WebDatasetOptions, export_webdataset, parse_splits};

/// The order of an epoch as a plain simulation: all streams run side by side; in each round
/// every stream with samples left fills its buffer up to `buffer` (or its end) from its shards
/// and hands one drawn uniformly from the buffer.
fn reference_order(layout: &StreamLayout, seed: u64) -> Vec<usize> {
    let mut starts = vec![0];
    for n in &layout.shard_samples {
        starts.push(starts.last().unwrap() + n);
    }
    struct Stream {
        input: std::collections::VecDeque<usize>,
        buf: Vec<usize>,
        rng: rand_chacha::ChaCha8Rng,
    }
    let mut streams: Vec<Stream> = layout
        .stream_shards(seed)
        .iter()
        .enumerate()
        .map(|(s, shards)| Stream {
            input: shards
                .iter()
                .flat_map(|&n| starts[n]..starts[n + 1])
                .collect(),
            buf: Vec::new(),
            rng: StreamLayout::buffer_rng(seed, s),
        })
        .collect();
    let mut out = Vec::new();
    while streams
        .iter()
        .any(|s| !s.input.is_empty() || !s.buf.is_empty())
    {
        for s in &mut streams {
            while s.buf.len() < layout.buffer {
                match s.input.pop_front() {
                    Some(i) => s.buf.push(i),
                    None => break,
                }
            }
            if !s.buf.is_empty() {
                let j = s.rng.random_range(0..s.buf.len());
                out.push(s.buf.swap_remove(j));
            }
        }
    }
    out
}

#[test]
fn the_epoch_order_is_a_permutation_that_follows_the_seeds_and_the_buffer() {
    let layout = StreamLayout {
        shard_samples: vec![7, 3, 9, 1, 6, 8, 4, 5, 2],
        streams: 3,
        buffer: 4,
    };
    let n = layout.len();
    // The shards are dealt round-robin: a partition, sizes within one of each other.
    let dealt = layout.stream_shards(epoch_seed(1, 0, 0));
    let mut all = dealt.concat();
    all.sort();
    assert_eq!(all, (0..9).collect::<Vec<_>>());
    assert!(dealt.iter().all(|s| s.len() == 3));
    let mut seen = HashSet::new();
    for seed in [1, 2] {
        for epoch in 0..3 {
            let s = epoch_seed(seed, 0, epoch);
            let order = layout.epoch_order(s);
            let mut sorted = order.indices.clone();
            sorted.sort();
            assert_eq!(
                sorted,
                (0..n).collect::<Vec<_>>(),
                "seed {seed} epoch {epoch}"
            );
            assert_eq!(order.indices, reference_order(&layout, s));
            // The stream of each entry is the one whose shards hold it.
            let dealt = layout.stream_shards(s);
            for (&i, &st) in order.indices.iter().zip(&order.streams) {
                assert!(layout.read_order(&dealt[st as usize]).contains(&i));
            }
            assert!(
                seen.insert(order.indices),
                "seed {seed} epoch {epoch} repeats an order"
            );
        }
    }
    // A buffer as large as a stream shuffles the stream fully; a buffer of one keeps the shard
    // order, which still changes with the epoch (the shards are permuted).
    for buffer in [1, 1000] {
        let l = StreamLayout {
            buffer,
            ..layout.clone()
        };
        let s = epoch_seed(5, 1, 2);
        assert_eq!(l.epoch_order(s).indices, reference_order(&l, s));
    }
    let one = StreamLayout {
        buffer: 1,
        streams: 1,
        ..layout.clone()
    };
    let order = one.epoch_order(epoch_seed(5, 1, 2)).indices;
    assert_eq!(
        order,
        one.read_order(&one.stream_shards(epoch_seed(5, 1, 2))[0])
    );
    assert_ne!(order, (0..n).collect::<Vec<_>>());
}

/// A crestereo-layout dataset of `count` 64×128 pairs exported as WebDataset shards of about
/// two samples each; returns the export's folder.
fn shards(dir: &Path, count: usize) -> std::path::PathBuf {
    shards_split(dir, count, "train=1")
}

/// [`shards`] split as `splits` says (`train=0.6,val=0.4`).
fn shards_split(dir: &Path, count: usize, splits: &str) -> std::path::PathBuf {
    let (src, out) = (dir.join("src"), dir.join("shards"));
    write_crestereo_dataset(&src, count, 128, 64, 21).unwrap();
    let summary = export_webdataset(
        &src,
        &out,
        None,
        &ReadOptions::default(),
        &WebDatasetOptions {
            shard_bytes: 40_000,
            shuffle_seed: 2,
            splits: parse_splits(splits).unwrap(),
            force: false,
        },
    )
    .unwrap();
    assert!(summary.shards >= 4, "{summary:?}");
    out
}

/// The sample ids of `splits` of the export at `root`, read by stereo-io alone.
fn ids_of(root: &Path, splits: &[&str]) -> Vec<String> {
    use stereo_io::StereoDataset;
    let ds = stereo_io::WebDataset::open_splits(root, splits).unwrap();
    (0..ds.len())
        .map(|i| ds.id(i).unwrap().to_string())
        .collect()
}

/// The ids of every sample two streamed epochs of `entry` hand the trainer.
fn ids_trained_on(entry: DatasetEntry) -> Result<Vec<String>, String> {
    let source = Arc::new(MixedSource::open(&[entry]).map_err(|e| format!("{e:#}"))?);
    let n = source.datasets[0].len();
    let layouts = source.stream_layouts(&StreamSettings {
        streams: 2,
        shuffle_buffer: 2,
    });
    let mut l = Loader::start(
        source.clone(),
        Planner::with_layouts(5, &[1.0], &[n], layouts),
        0,
        AugmentConfig::none([32, 64]),
        2,
        2,
        0,
    );
    assert!(l.streams.is_some());
    Ok((0..2 * n)
        .map(|_| {
            let s = l.next_sample().unwrap();
            source.datasets[0].id(s.index).unwrap().to_string()
        })
        .collect())
}

/// A two-split export trains on `train` alone unless told otherwise: the samples the loader
/// hands out over two epochs are exactly the train split's, twice; `splits = ["val"]` gives
/// val's; a split the export lacks is an error listing the ones it has.
#[test]
fn a_two_split_export_trains_on_its_train_split_unless_told() {
    let dir = tempfile::tempdir().unwrap();
    let data = shards_split(dir.path(), 10, "train=0.6,val=0.4");
    let (train, val) = (ids_of(&data, &["train"]), ids_of(&data, &["val"]));
    assert_eq!((train.len(), val.len()), (6, 4));
    assert!(train.iter().all(|t| !val.contains(t)));
    let entry = |splits: Option<&[&str]>| DatasetEntry {
        splits: splits.map(|s| s.iter().map(|x| x.to_string()).collect()),
        ..DatasetEntry::new(data.clone())
    };
    let twice = |ids: &[String]| {
        let mut v = [ids, ids].concat();
        v.sort();
        v
    };
    let sorted = |mut v: Vec<String>| {
        v.sort();
        v
    };
    assert_eq!(sorted(ids_trained_on(entry(None)).unwrap()), twice(&train));
    assert_eq!(
        sorted(ids_trained_on(entry(Some(&["val"]))).unwrap()),
        twice(&val)
    );
    let both = sorted(ids_trained_on(entry(Some(&["val", "train"]))).unwrap());
    assert_eq!(both, twice(&[train.clone(), val.clone()].concat()));
    let e = ids_trained_on(entry(Some(&["test"]))).unwrap_err();
    assert!(
        e.contains("no split \"test\"") && e.contains("its splits: train, val"),
        "{e}"
    );
    // The log line names the split.
    let source = MixedSource::open(&[entry(None)]).unwrap();
    assert!(
        source.names[0].contains("(webdataset split train, 6 samples)"),
        "{}",
        source.names[0]
    );
}

/// Without a `train` split, several splits are never mixed silently (train and evaluation ask
/// which), a single split is used as it is, and evaluation takes `val`, else `test`.
#[test]
fn split_defaults_without_a_train_split_and_for_evaluation() {
    use crestereo_train::data::{SplitUse, choose_splits};
    let dir = tempfile::tempdir().unwrap();
    let two = shards_split(&dir.path().join("two"), 8, "a=0.5,b=0.5");
    let e = format!(
        "{:#}",
        MixedSource::open(&[DatasetEntry::new(two.clone())])
            .err()
            .unwrap()
    );
    assert!(
        e.contains("splits a, b and no `train` split") && e.contains("DIR:webdataset:SPLIT"),
        "{e}"
    );
    let e = choose_splits(&two, None, SplitUse::Eval, "--data")
        .unwrap_err()
        .to_string();
    assert!(e.contains("no `val` or `test` split"), "{e}");
    let pick = |root: &Path, purpose| choose_splits(root, None, purpose, "k").unwrap();
    let one = shards_split(&dir.path().join("one"), 8, "holdout=1");
    assert_eq!(pick(&one, SplitUse::Train), ["holdout"]);
    assert_eq!(pick(&one, SplitUse::Eval), ["holdout"]);
    let three = shards_split(&dir.path().join("three"), 8, "train=0.5,test=0.25,val=0.25");
    assert_eq!(pick(&three, SplitUse::Train), ["train"]);
    assert_eq!(pick(&three, SplitUse::Eval), ["val"]);
    let tt = shards_split(&dir.path().join("tt"), 8, "train=0.5,test=0.5");
    assert_eq!(pick(&tt, SplitUse::Eval), ["test"]);
}

#[test]
fn streamed_samples_match_a_resume_other_threads_and_random_access() {
    let dir = tempfile::tempdir().unwrap();
    let data = shards(dir.path(), 12);
    let source = Arc::new(
        MixedSource::open(&[DatasetEntry {
            format: Some(stereo_io::DatasetFormat::WebDataset),
            ..DatasetEntry::new(data.clone())
        }])
        .unwrap(),
    );
    let settings = StreamSettings {
        streams: 2,
        shuffle_buffer: 3,
    };
    let layouts = source.stream_layouts(&settings);
    assert!(layouts[0].is_some());
    let planner = || Planner::with_layouts(7, &[1.0], &[12], layouts.clone());
    let augment = AugmentConfig {
        crop: [32, 64],
        ..AugmentConfig::default()
    };
    let (prefetch, buffer) = (4, 3);
    let take = |start: u64, workers: usize, n: usize| {
        let mut l = Loader::start(
            source.clone(),
            planner(),
            start,
            augment.clone(),
            workers,
            prefetch,
            1,
        );
        let got: Vec<_> = (0..n).map(|_| l.next_sample().unwrap()).collect();
        assert!(l.skipped.lock().unwrap().is_empty());
        let streams = l.streams.clone().expect("the WebDataset is streamed");
        (got, streams.peak_buffered())
    };
    let (one, peak_one) = take(0, 1, 30);
    let (many, peak_many) = take(0, 3, 30);
    let (resumed, peak_resumed) = take(17, 2, 13);
    // Every planned sample comes from its stream, and each epoch of 12 covers every sample.
    for epoch in one.chunks(12).take(2) {
        let mut idx: Vec<usize> = epoch.iter().map(|s| s.index).collect();
        idx.sort();
        assert_eq!(idx, (0..12).collect::<Vec<_>>());
        assert!(epoch.iter().all(|s| s.plan.stream.is_some()));
    }
    assert_ne!(
        one[..12].iter().map(|s| s.index).collect::<Vec<_>>(),
        one[12..24].iter().map(|s| s.index).collect::<Vec<_>>(),
        "two epochs in the same order"
    );
    for (a, b) in one.iter().zip(&many) {
        assert_eq!((a.plan, a.index), (b.plan, b.index));
        assert!(
            a.sample == b.sample,
            "sample {} differs on 3 threads",
            a.plan.ordinal
        );
    }
    for (a, b) in one[17..].iter().zip(&resumed) {
        assert_eq!((a.plan, a.index), (b.plan, b.index));
        assert!(
            a.sample == b.sample,
            "resumed stream differs at {}",
            a.plan.ordinal
        );
    }
    // The streamed bytes are the planned sample's: random access gives the same arrays.
    for s in &one {
        let raw = source.datasets[0].sample(s.index).unwrap();
        assert!(augment_random(&raw, &augment, s.plan.seed) == s.sample);
    }
    // A stream's buffer holds its shuffle buffer, plus what threads asked for ahead of turn.
    for peak in [peak_one, peak_many, peak_resumed] {
        assert!(
            peak >= buffer - 1 && peak <= buffer + prefetch + 3,
            "peak {peak}"
        );
    }
}

#[test]
fn streaming_off_reads_the_webdataset_by_seeking_in_a_full_shuffle() {
    let dir = tempfile::tempdir().unwrap();
    let data = shards(dir.path(), 8);
    let source = Arc::new(MixedSource::open(&[DatasetEntry::new(data)]).unwrap());
    let off = source.stream_layouts(&StreamSettings {
        streams: 0,
        shuffle_buffer: 10,
    });
    assert_eq!(off, vec![None]);
    let mut l = Loader::start(
        source.clone(),
        Planner::with_layouts(3, &[1.0], &[8], off),
        0,
        AugmentConfig::none([32, 64]),
        2,
        2,
        0,
    );
    assert!(l.streams.is_none());
    let mut idx: Vec<usize> = (0..8).map(|_| l.next_sample().unwrap().index).collect();
    idx.sort();
    assert_eq!(idx, (0..8).collect::<Vec<_>>());
}
