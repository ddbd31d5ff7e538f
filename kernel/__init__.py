"""The shared kernel: file formats (the BOP data-set layout, template sets), rigid transforms, the pinhole
projection, the pictures' drawing helpers, whole-file writes and the user-error type. The generator
(`syneepose`), the estimator (`feepe`) and the evaluator (`eval`) import it; it imports none of them, so
FEEPE runs on a camera's frames without the generator."""
