import time, tempfile, os
import numpy as np
if __name__ == "__main__":
    import pyarrow as pa, pyarrow.parquet as pq
    from tepinn_flight.sim.simulate import simulate_record
    rec = simulate_record("agile_quad", 60.0, 400.0, 1)
    df = rec.data
    table = pa.Table.from_pandas(df, preserve_index=False)
    d = tempfile.mkdtemp(); p = os.path.join(d, "x.parquet")
    dict_cols = [f.name for f in table.schema if not pa.types.is_floating(f.type)]
    def best(fn, n=7):
        ts = []
        for _ in range(n):
            t = time.process_time(); fn(); ts.append(time.process_time() - t)
        return min(ts) * 1e3
    print("from_pandas", best(lambda: pa.Table.from_pandas(df, preserve_index=False)))
    print("from_pandas nthreads1", best(lambda: pa.Table.from_pandas(df, preserve_index=False, nthreads=1)))
    print("from arrays", best(lambda: pa.table({c: df[c].to_numpy() for c in df.columns})))
    for kw in [dict(compression="zstd"), dict(compression="zstd", compression_level=1), dict(compression="zstd", compression_level=-1),
               dict(compression="zstd", compression_level=3), dict(compression="lz4"), dict(compression="snappy"), dict(compression="none"),
               dict(compression="zstd", write_statistics=False), dict(compression="zstd", data_page_size=1<<20)]:
        ms = best(lambda: pq.write_table(table, p, use_dictionary=dict_cols, **kw))
        print(kw, f"{ms:.1f} ms", os.path.getsize(p))
